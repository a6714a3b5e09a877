"""The frozen encoder of CLIPort's RN50-BERT ablation: an ImageNet ResNet-50 trunk and a DistilBERT sentence encoder.

Image trunk: torchvision's ResNet-50 architecture; the five levels are the stem (conv1, bn1, relu,
maxpool; 64 channels, stride 4) and layer1..layer4 (256, 512, 1024, 2048 channels at strides 4, 8, 16,
32). Its classifier head (``avgpool``, ``fc``) is dropped. Images are normalised with the ImageNet
mean and standard deviation, the statistics these weights were trained with. This is a deliberate
difference from the reference CLIPort, whose RN50-BERT ablation fed the ImageNet ResNet images
normalised with CLIP's statistics.

Sentence encoder: ``distilbert-base-uncased``'s architecture (``transformers.DistilBertModel``); a
sentence is the mean of ``last_hidden_state`` over its real tokens (768 wide; CLIPort takes the
plain mean over the tokens of one unpadded sentence, which is the same thing). The decoder puts a
trainable Linear 768 -> 1024 on it (:attr:`FrozenRN50BERT.sentence_projection`, CLIPort's
``text_fc``). DistilBERT reads at most :data:`MAX_TOKENS` tokens, ``[CLS]`` and ``[SEP]`` included.

Weight sources of the trunk (``rn50_weights`` in the agent configs):

- ``"imagenet"``: torchvision's ``ResNet50_Weights.IMAGENET1K_V1`` (what CLIPort's
  ``resnet50(pretrained=True)`` loaded), taken from torch's hub cache
  (``torch.hub.get_dir()/checkpoints/``) when present, otherwise downloaded from download.pytorch.org.
  Without network this fails within seconds with :class:`RN50WeightsUnavailable`, which lists the
  offline options.
- a path to a local file: a state dict of torchvision's ``resnet50`` (``.pt``/``.pth``/``.bin`` or
  ``.safetensors``). The classifier's ``fc.*`` tensors may be present and are ignored (the head is not
  used); every other tensor must be there with its shape. Batch norms' ``num_batches_tracked``
  counters, absent from some older files, may be missing (they play no part in eval mode).
- ``"random"``: a seeded (seed 0) random initialisation whose batch-norm statistics are calibrated
  on noise so that its features keep unit scale (tests and benchmarks only).

Weight sources of the sentence encoder (``bert_weights``):

- ``"distilbert-base-uncased"`` or any other Hugging Face repo id of a DistilBERT model: taken from the
  Hugging Face cache when it holds the model and its tokenizer, otherwise downloaded. Without network
  (or with ``HF_HUB_OFFLINE`` set) this fails within seconds with :class:`BERTWeightsUnavailable`.
- a path to a local folder written by ``save_pretrained`` of the model and of its tokenizer:
  ``config.json``, the weights (``model.safetensors`` or ``pytorch_model.bin``) and ``vocab.txt``
  (or ``tokenizer.json``). Head tensors of a ``DistilBertFor...`` checkpoint are ignored; every tensor
  of the DistilBERT body must be there.
- ``"random"``: a seeded (seed 0) random ``DistilBertModel(DistilBertConfig())`` with the
  ``distilbert-base-uncased`` architecture, and, since no vocabulary file exists offline, a
  deterministic word-hashing tokenizer (:class:`HashingTokenizer`). Tests and benchmarks only.

A failed load never falls back to ``"random"``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import torch
from torch import nn

from cliport.errors import UserError
from cliport.models import weights
from cliport.models.encoders import FrozenEncoder

TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
SENTENCE_DIM = 768
SENTENCE_PROJECTION = 1024
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
RANDOM_SEED = 0
#: DistilBERT reads at most this many tokens of an instruction, [CLS] and [SEP] included.
MAX_TOKENS = 512
DEFAULT_BERT = "distilbert-base-uncased"
_TORCHVISION_HOST = ("download.pytorch.org", 443)
_RESNET_WHAT = "torchvision resnet50 (fc.* ignored)"
_WEIGHT_FILES = (
    "model.safetensors",
    "model.safetensors.index.json",
    "pytorch_model.bin",
    "pytorch_model.bin.index.json",
)
_VOCAB_FILES = ("vocab.txt", "tokenizer.json")
# A Hugging Face repo id: "name" or "owner/name", letters, digits and - _ . only.
_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*(/[\w.-]+)?$")



class RN50WeightsUnavailable(UserError, RuntimeError):
    """The requested ResNet-50 weights could not be loaded."""


class BERTWeightsUnavailable(UserError, RuntimeError):
    """The requested DistilBERT weights (or its tokenizer) could not be loaded."""


# --------------------------------------------------------------------------------------------------
# ResNet-50 trunk


class ResNet50Trunk(nn.Module):
    """torchvision's ResNet-50 without its classifier head, returning the five trunk levels.

    Submodule names are torchvision's (``conv1``, ``bn1``, ``layer1`` ...), so its state dict is a
    torchvision ``resnet50`` state dict without the ``fc.*`` tensors.
    """

    def __init__(self, resnet: nn.Module) -> None:
        super().__init__()
        self.conv1 = resnet.conv1
        self.bn1 = resnet.bn1
        self.relu = resnet.relu
        self.maxpool = resnet.maxpool
        self.layer1 = resnet.layer1
        self.layer2 = resnet.layer2
        self.layer3 = resnet.layer3
        self.layer4 = resnet.layer4

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Normalised images (N, 3, H, W) -> [(N, 64, H/4, W/4), (N, 256, H/4, W/4), (N, 512, H/8, W/8),
        (N, 1024, H/16, W/16), (N, 2048, H/32, W/32)]."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        levels = [x]
        for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
            x = layer(x)
            levels.append(x)
        return levels


def _bad_rn50_file(path: Path, reason: str) -> RN50WeightsUnavailable:
    return RN50WeightsUnavailable(f"Cannot load RN50 weights from {path}: {reason}")


def _imagenet_weights() -> Any:
    from torchvision.models import ResNet50_Weights

    return ResNet50_Weights.IMAGENET1K_V1


def imagenet_cache_file() -> Path:
    """Where torch's hub cache keeps torchvision's ImageNet ResNet-50 weights (the file may not exist)."""
    name = os.path.basename(urlparse(_imagenet_weights().url).path)
    return Path(torch.hub.get_dir()) / "checkpoints" / name


def _download_reachable(timeout_s: float = 3.0) -> bool:
    """Whether download.pytorch.org answers a TCP connection within `timeout_s` seconds."""
    return weights.host_reachable(*_TORCHVISION_HOST, timeout_s=timeout_s)


def _rn50_offline_help(source: str, reason: str) -> str:
    url = _imagenet_weights().url
    return (
        f"Cannot load RN50 weights '{source}': {reason}\n"
        "Options without network:\n"
        f"  * copy {url} (downloaded on a machine with network) to {imagenet_cache_file()};\n"
        "  * copy a torchvision resnet50 state dict (.pt/.pth/.bin/.safetensors) to this machine and set "
        "rn50_weights = '/path/to/file';\n"
        "  * for tests and benchmarks only, set rn50_weights = 'random' (seeded random initialisation)."
    )


def _resnet50() -> nn.Module:
    """torchvision's resnet50, seeded (seed 0) without touching the caller's random state."""
    from torchvision.models import resnet50

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(RANDOM_SEED)
        return resnet50(weights=None)


def _load_trunk_state(trunk: ResNet50Trunk, path: Path, state: Mapping[str, torch.Tensor]) -> ResNet50Trunk:
    """Load a torchvision resnet50 state dict into ``trunk`` strictly (``fc.*`` dropped); errors name ``path``."""
    expected = trunk.state_dict()
    state = {k: v for k, v in state.items() if not k.startswith("fc.")}
    counters = [k for k in expected if k.endswith(".num_batches_tracked")]
    if not any(k in state for k in counters):
        state.update({k: expected[k] for k in counters})
    weights.check_architecture(path, state, expected, _RESNET_WHAT, _bad_rn50_file)
    trunk.load_state_dict(state, strict=True)
    return trunk


def build_rn50_trunk(source: str) -> ResNet50Trunk:
    """The ResNet-50 trunk with weights from ``source`` ("imagenet", a state-dict file, or "random").

    Returned in eval mode; raises :class:`RN50WeightsUnavailable` (one line naming the file for a bad
    file, the offline options when "imagenet" cannot be had).
    """
    if source == "random":
        trunk = ResNet50Trunk(_resnet50())
        weights.calibrate_batch_norm(trunk, trunk, seed=RANDOM_SEED)
        return trunk.eval()
    if source == "imagenet":
        cached = imagenet_cache_file()
        if cached.is_file():
            return _load_trunk_state(
                ResNet50Trunk(_resnet50()), cached, weights.load_state_dict_file(cached, _bad_rn50_file)
            ).eval()
        if not _download_reachable():
            raise RN50WeightsUnavailable(
                _rn50_offline_help(
                    source, f"the weights are not cached at {cached} and download.pytorch.org is unreachable."
                )
            )
        try:
            state = _imagenet_weights().get_state_dict(progress=False)
        except Exception as err:  # urllib, hash checks and torch.load raise assorted errors for a failed download
            raise RN50WeightsUnavailable(_rn50_offline_help(source, weights.first_sentence(err) + ".")) from err
        return _load_trunk_state(ResNet50Trunk(_resnet50()), cached, state).eval()
    path = Path(source).expanduser()
    if not path.is_file():
        raise RN50WeightsUnavailable(
            _rn50_offline_help(source, "it is neither 'imagenet', 'random' nor an existing file.")
        )
    state = weights.load_state_dict_file(path, _bad_rn50_file)
    return _load_trunk_state(ResNet50Trunk(_resnet50()), path, state).eval()


# --------------------------------------------------------------------------------------------------
# DistilBERT sentence encoder


class HashingTokenizer:
    """The tokenizer of the ``"random"`` DistilBERT only: words hashed to ids, no vocabulary file needed.

    Lowercases, splits into words and punctuation marks, and maps each to an id in [1000, 30522) with
    ``zlib.crc32`` (deterministic across runs and machines); ``[CLS]`` = 101 first, ``[SEP]`` = 102 last,
    ``[PAD]`` = 0. The ids mean nothing to a trained DistilBERT; they only give a random one distinct,
    reproducible inputs. Called like a Hugging Face tokenizer, for the arguments this module uses.
    """

    pad_id, cls_id, sep_id = 0, 101, 102
    first_word_id, vocab_size = 1000, 30522
    _words = re.compile(r"\w+|[^\w\s]")

    def _ids(self, text: str) -> list[int]:
        span = self.vocab_size - self.first_word_id
        words = self._words.findall(text.lower())
        return [self.first_word_id + zlib.crc32(w.encode("utf-8")) % span for w in words]

    def __call__(
        self,
        texts: str | list[str],
        padding: bool = False,
        truncation: bool = False,
        max_length: int | None = None,
        return_tensors: str | None = None,
        verbose: bool = True,
    ) -> dict[str, Any]:
        """``{"input_ids", "attention_mask"}`` of one text (lists) or of a batch (padded (B, L) tensors with
        ``return_tensors="pt"``)."""
        batch = [texts] if isinstance(texts, str) else list(texts)
        rows = []
        for text in batch:
            ids = self._ids(text)
            if truncation and max_length is not None:
                ids = ids[: max_length - 2]
            rows.append([self.cls_id, *ids, self.sep_id])
        width = max(len(r) for r in rows) if padding else None
        masks = [[1] * len(r) + [0] * ((width or len(r)) - len(r)) for r in rows]
        rows = [r + [self.pad_id] * ((width or len(r)) - len(r)) for r in rows]
        if return_tensors == "pt":
            return {"input_ids": torch.tensor(rows), "attention_mask": torch.tensor(masks)}
        if isinstance(texts, str):
            return {"input_ids": rows[0], "attention_mask": masks[0]}
        return {"input_ids": rows, "attention_mask": masks}


def _bad_bert_folder(path: Path, reason: str) -> BERTWeightsUnavailable:
    return BERTWeightsUnavailable(f"Cannot load DistilBERT weights from {path}: {reason}")


def _hub_reachable(timeout_s: float = 3.0) -> bool:
    """Whether the Hugging Face hub answers within `timeout_s` seconds (False when HF_HUB_OFFLINE is set)."""
    return weights.hf_hub_reachable(timeout_s)


def _hf_cache_dir() -> str:
    from huggingface_hub import constants

    return str(constants.HF_HUB_CACHE)


def _bert_offline_help(source: str, reason: str) -> str:
    return (
        f"Cannot load DistilBERT weights '{source}': {reason}\n"
        "Options without network:\n"
        "  * on a machine with network, save DistilBertModel.from_pretrained(name) and its tokenizer with "
        "save_pretrained into one folder (config.json, model.safetensors, vocab.txt), copy it here and set "
        "bert_weights = '/path/to/folder';\n"
        f"  * pre-populate the Hugging Face cache ({_hf_cache_dir()}, under HF_HOME) with {source} on a machine "
        "with network;\n"
        "  * for tests and benchmarks only, set bert_weights = 'random' (seeded random initialisation)."
    )


def _missing_files(folder: Path) -> list[str]:
    """What a ``save_pretrained`` folder of a DistilBERT model and its tokenizer lacks, in words."""
    missing = []
    if not (folder / "config.json").is_file():
        missing.append("config.json")
    if not any((folder / name).is_file() for name in _WEIGHT_FILES):
        missing.append("the weights (model.safetensors or pytorch_model.bin)")
    if not any((folder / name).is_file() for name in _VOCAB_FILES):
        missing.append("the tokenizer's vocab.txt (or tokenizer.json)")
    return missing


class _QuietTransformersLoad(logging.Filter):
    """Drops transformers' report of unused or missing tensors; :func:`_load_bert_folder` checks those itself."""

    _phrases = ("LOAD REPORT", "Some weights of the model checkpoint", "Some weights of DistilBertModel")

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(p in message for p in self._phrases)


@contextlib.contextmanager
def _quiet_transformers() -> Iterator[None]:
    """No "Loading weights" progress bar and no loading report while a checked local folder is read."""
    from transformers.utils import logging as hf_logging

    bars = hf_logging.is_progress_bar_enabled()
    named = logging.getLogger("transformers.modeling_utils")
    quiet = _QuietTransformersLoad()
    named.addFilter(quiet)
    if bars:
        # Only transformers' own flag: its disable_progress_bar() would switch off huggingface_hub's bars too.
        hf_logging._tqdm_active = False
    try:
        yield
    finally:
        named.removeFilter(quiet)
        if bars:
            hf_logging._tqdm_active = True


def _load_bert_folder(folder: Path, label: Path | str) -> tuple[nn.Module, Any]:
    """DistilBertModel and its tokenizer from a ``save_pretrained`` folder; one-line errors naming ``label``."""
    from safetensors import SafetensorError
    from transformers import DistilBertConfig, DistilBertModel, DistilBertTokenizerFast

    where = Path(label)
    if not folder.exists():
        raise _bad_bert_folder(where, "no such folder")
    if not folder.is_dir():
        raise _bad_bert_folder(where, "a file; bert_weights needs a folder written by save_pretrained")
    missing = _missing_files(folder)
    if missing:
        raise _bad_bert_folder(
            where, f"missing {', '.join(missing)}; save the model and its tokenizer there with save_pretrained"
        )
    try:
        model_type = json.loads((folder / "config.json").read_text()).get("model_type")
    except (OSError, ValueError, AttributeError) as err:
        raise _bad_bert_folder(where, f"config.json is not a JSON object ({weights.first_sentence(err)})") from None
    if model_type != "distilbert":
        raise _bad_bert_folder(where, f"config.json describes a '{model_type}' model, not a DistilBERT one")
    try:
        with _quiet_transformers():
            config = DistilBertConfig.from_pretrained(str(folder), local_files_only=True)
            model, info = DistilBertModel.from_pretrained(
                str(folder), config=config, local_files_only=True, output_loading_info=True
            )
            tokenizer = DistilBertTokenizerFast.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError, RuntimeError, KeyError, SafetensorError) as err:  # errors for broken files
        raise _bad_bert_folder(where, f"not a loadable DistilBERT checkpoint ({weights.first_sentence(err)})") from None
    problems = []
    if info.get("missing_keys"):
        keys = sorted(info["missing_keys"])
        problems.append(f"{len(keys)} tensors missing (e.g. {keys[0]})")
    if info.get("mismatched_keys"):
        keys = sorted(str(k[0] if isinstance(k, tuple) else k) for k in info["mismatched_keys"])
        problems.append(f"{len(keys)} with other shapes (e.g. {keys[0]})")
    if problems:
        raise _bad_bert_folder(where, f"not a DistilBERT checkpoint: {'; '.join(problems)}")
    return model.eval(), tokenizer


def _cached_bert_folder(repo_id: str) -> Path | None:
    """The Hugging Face cache's snapshot folder of ``repo_id`` if it holds the model and its tokenizer."""
    from huggingface_hub import try_to_load_from_cache

    found = try_to_load_from_cache(repo_id, "config.json")
    if not isinstance(found, str):
        return None
    folder = Path(found).parent
    return None if _missing_files(folder) else folder


def _random_bert() -> tuple[nn.Module, HashingTokenizer]:
    from transformers import DistilBertConfig, DistilBertModel

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(RANDOM_SEED)
        model = DistilBertModel(DistilBertConfig())
    return model.eval(), HashingTokenizer()


def build_distilbert(source: str) -> tuple[nn.Module, Any]:
    """DistilBertModel (eval mode) and its tokenizer from ``source``.

    ``source``: a Hugging Face repo id such as "distilbert-base-uncased" (cache first, then download), a
    ``save_pretrained`` folder, or "random". Raises :class:`BERTWeightsUnavailable`.
    """
    if source == "random":
        return _random_bert()
    path = Path(source).expanduser()
    if path.exists() or not _REPO_ID.match(source) or ".." in source:
        return _load_bert_folder(path, source)
    cached = _cached_bert_folder(source)
    if cached is not None:
        return _load_bert_folder(cached, cached)
    if not _hub_reachable():
        reason = "it is not a local folder, not in the Hugging Face cache, and the hub is unreachable"
        if weights.hf_hub_offline():
            reason += " (HF_HUB_OFFLINE is set)"
        raise BERTWeightsUnavailable(_bert_offline_help(source, reason + "."))
    try:
        from transformers import DistilBertModel, DistilBertTokenizerFast

        # Fills the cache with what the model and the tokenizer need (with the hub's download bars); read back
        # below through the checked path, which reports what the loading report would.
        with _quiet_transformers():
            DistilBertModel.from_pretrained(source)
            DistilBertTokenizerFast.from_pretrained(source)
    except Exception as err:  # hub and transformers raise assorted errors for failed downloads and foreign repos
        raise BERTWeightsUnavailable(_bert_offline_help(source, weights.first_sentence(err) + ".")) from err
    cached = _cached_bert_folder(source)
    if cached is None:
        raise BERTWeightsUnavailable(_bert_offline_help(source, "the download left no complete copy in the cache."))
    return _load_bert_folder(cached, cached)


# --------------------------------------------------------------------------------------------------
# The encoder


class FrozenRN50BERT(FrozenEncoder):
    """Frozen ImageNet ResNet-50 trunk levels (stem, layer1..4) and DistilBERT sentence features (768)."""

    trunk_channels = TRUNK_CHANNELS
    sentence_dim = SENTENCE_DIM
    sentence_projection = SENTENCE_PROJECTION

    def __init__(
        self, trunk: ResNet50Trunk, bert: nn.Module, tokenizer: Any, rn50_source: str, bert_source: str
    ) -> None:
        super().__init__()
        self.trunk = trunk
        self.bert = bert
        self.tokenizer = tokenizer
        self.rn50_source = rn50_source
        self.bert_source = bert_source
        self.max_tokens = min(MAX_TOKENS, int(getattr(bert.config, "max_position_embeddings", MAX_TOKENS)))
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.freeze()

    def sources(self) -> dict[str, str]:
        return {"rn50_weights": self.rn50_source, "bert_weights": self.bert_source}

    def image_module(self) -> nn.Module:
        return self.trunk

    def count_tokens(self, text: str) -> int:
        """DistilBERT tokens of ``text``, [CLS] and [SEP] included (before truncation)."""
        return len(self.tokenizer(text, verbose=False)["input_ids"])

    def instruction_note(self, text: str) -> str | None:
        n_tokens = self.count_tokens(text)
        if n_tokens > self.max_tokens:
            return f"the instruction has {n_tokens} DistilBERT tokens; DistilBERT reads the first {self.max_tokens}"
        return None

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """RGB (N, 3, H, W) in [0, 1] -> five levels (N, C_i, H / s_i, W / s_i), ImageNet-normalised input."""
        x = ((rgb - self.mean) / self.std).to(self.image_dtype())
        return self.trunk(x)

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        """Instructions (B,) -> (B, 768): mean of DistilBERT's last hidden states over each one's real tokens."""
        batch = self.tokenizer(texts, padding=True, truncation=True, max_length=self.max_tokens, return_tensors="pt")
        device = self.mean.device
        ids = batch["input_ids"].to(device)
        mask = batch["attention_mask"].to(device)
        hidden = self.bert(input_ids=ids, attention_mask=mask).last_hidden_state  # (B, L, 768)
        weight = mask.unsqueeze(-1).to(hidden.dtype)
        return (hidden * weight).sum(dim=1) / weight.sum(dim=1).clamp(min=1)


def load_rn50_bert(rn50_source: str, bert_source: str) -> FrozenRN50BERT:
    """Load the frozen RN50-BERT encoder.

    ``rn50_source``: "imagenet", a torchvision resnet50 state-dict file, or "random"; ``bert_source``:
    "distilbert-base-uncased" (or another DistilBERT repo id), a ``save_pretrained`` folder, or "random".
    Raises :class:`RN50WeightsUnavailable` / :class:`BERTWeightsUnavailable` with one line naming the
    source and the problem.
    """
    trunk = build_rn50_trunk(rn50_source)
    bert, tokenizer = build_distilbert(bert_source)
    return FrozenRN50BERT(trunk, bert, tokenizer, rn50_source, bert_source)
