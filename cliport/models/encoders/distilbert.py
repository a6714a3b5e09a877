"""The sentence encoder of CLIPort's RN50-BERT ablation: DistilBERT, its tokenizer and its weight sources.

The architecture is ``distilbert-base-uncased``'s (``transformers.DistilBertModel``); how a sentence
feature is read from it is :class:`cliport.models.encoders.rn50_bert_encoder.FrozenRN50BERT`'s.

Weight sources (``bert_weights`` in the agent configs):

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
import re
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import torch
from torch import nn

from cliport.errors import UserError
from cliport.models.encoders import weights
from cliport.utils import hub

RANDOM_SEED = 0
DEFAULT_BERT = "distilbert-base-uncased"
_WEIGHT_FILES = (
    "model.safetensors",
    "model.safetensors.index.json",
    "pytorch_model.bin",
    "pytorch_model.bin.index.json",
)
_VOCAB_FILES = ("vocab.txt", "tokenizer.json")
# A Hugging Face repo id: "name" or "owner/name", letters, digits and - _ . only.
_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*(/[\w.-]+)?$")


class BERTWeightsUnavailable(UserError, RuntimeError):
    """The requested DistilBERT weights (or its tokenizer) could not be loaded."""


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
    return hub.hf_hub_reachable(timeout_s)


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
            # output_loading_info=True returns (model, loading info); transformers' annotation names the model only.
            model, info = cast(
                tuple[DistilBertModel, dict[str, Any]],
                DistilBertModel.from_pretrained(
                    str(folder), config=config, local_files_only=True, output_loading_info=True
                ),
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
        if hub.hf_hub_offline():
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
