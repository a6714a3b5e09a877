"""One frozen open_clip RN50 shared by every semantic stream: image trunk features and sentence features.

Weight sources (``clip_weights`` in the agent configs):

- ``"openai"``: open_clip's tag for OpenAI's RN50 weights, taken from the Hugging Face cache when
  present, otherwise downloaded. Without network this fails within seconds with
  :class:`CLIPWeightsUnavailable`, which lists the offline options.
- a path to a local file: a state dict (``.pt``/``.pth``/``.bin`` or ``.safetensors``) of
  ``RN50-quickgelu``, or OpenAI's own TorchScript ``RN50.pt``.
- ``"random"``: a random initialisation, seeded (seed 0) so that reloading a checkpoint reproduces it.
  Only when asked for explicitly; a failed load never falls back to it.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from cliport.errors import UserError
from cliport.models import weights
from cliport.models.encoders import FrozenEncoder

MODEL_NAME = "RN50-quickgelu"
SENTENCE_DIM = 1024
# Channels of the trunk's intermediate features: stem, layer1..layer4 (strides 4, 4, 8, 16, 32).
TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
RANDOM_SEED = 0
# CLIP reads at most this many tokens of an instruction, start and end tokens included; the tokenizer
# cuts the rest off without saying so.
CONTEXT_LENGTH = 77
_RANDOM_INIT_WARNING = "No pretrained weights loaded for model"

log = logging.getLogger(__name__)
_warned_long_instructions: set[str] = set()


class CLIPWeightsUnavailable(UserError, RuntimeError):
    """The requested CLIP weights could not be loaded."""


def _offline_help(source: str, reason: str) -> str:
    return (
        f"Cannot load CLIP weights '{source}': {reason}\n"
        "Options without network:\n"
        "  * copy OpenAI's RN50.pt (TorchScript) or an open_clip RN50-quickgelu state dict "
        "(.pt/.pth/.bin/.safetensors) to this machine and set clip_weights = '/path/to/file';\n"
        "  * pre-populate the Hugging Face cache (HF_HOME) with timm/resnet50_clip.openai on a machine "
        "with network;\n"
        "  * for tests and benchmarks only, set clip_weights = 'random' (seeded random initialisation)."
    )


class _OpenCLIPLogFilter(logging.Filter):
    """Drops open_clip's INFO records, and its random-initialisation warning where that was asked for.

    open_clip (3.x) logs through the root logger (``logging.info(...)``), so a level on an
    ``open_clip`` logger does not reach those records; this filter sits on the root logger instead.
    """

    def __init__(self, expect_random_init: bool) -> None:
        super().__init__()
        self.expect_random_init = expect_random_init

    def filter(self, record: logging.LogRecord) -> bool:
        from_open_clip = record.name.startswith("open_clip") or f"{os.sep}open_clip{os.sep}" in record.pathname
        if not from_open_clip:
            return True
        if record.levelno < logging.WARNING:
            return False
        return not (self.expect_random_init and record.getMessage().startswith(_RANDOM_INIT_WARNING))


@contextlib.contextmanager
def _quiet_open_clip(expect_random_init: bool = False) -> Iterator[None]:
    """Keep open_clip's INFO lines (and, when the random init is intended, its warning about it) quiet."""
    named = logging.getLogger("open_clip")
    if named.level == logging.NOTSET:
        named.setLevel(logging.WARNING)
    root = logging.getLogger()
    quiet = _OpenCLIPLogFilter(expect_random_init)
    root.addFilter(quiet)
    try:
        yield
    finally:
        root.removeFilter(quiet)


def _hub_reachable(timeout_s: float = 3.0) -> bool:
    """Whether the Hugging Face hub answers a TCP connection within `timeout_s` seconds (False if HF_HUB_OFFLINE)."""
    return weights.hf_hub_reachable(timeout_s)


def _cached_openai_file() -> str | None:
    """Path of open_clip's OpenAI RN50 weights in the local Hugging Face cache, if they are there."""
    import open_clip.pretrained
    from huggingface_hub import try_to_load_from_cache

    cfg = open_clip.pretrained.get_pretrained_cfg(MODEL_NAME, "openai")
    repo_id = cfg["hf_hub"].rstrip("/")
    for filename in ("open_clip_model.safetensors", "open_clip_pytorch_model.bin"):
        found = try_to_load_from_cache(repo_id, filename)
        if isinstance(found, str):
            return found
    return None


def _bad_file(path: Path, reason: str) -> CLIPWeightsUnavailable:
    return CLIPWeightsUnavailable(f"Cannot load CLIP weights from {path}: {reason}")


_first_sentence = weights.first_sentence  # the name build_clip_model uses


def _load_state_dict_file(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of a state-dict file; CLIPWeightsUnavailable naming the file if it is not one."""
    return weights.load_state_dict_file(path, _bad_file)


def _check_architecture(path: Path, state: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor]) -> None:
    """CLIPWeightsUnavailable with a short account if ``state`` is not a state dict of ``expected``'s model."""
    weights.check_architecture(path, state, expected, f"open_clip {MODEL_NAME}", _bad_file)


def _is_torchscript(path: Path) -> bool:
    """TorchScript archives (OpenAI's RN50.pt) hold compiled code next to the tensors."""
    if not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as archive:
        return any(name.endswith("constants.pkl") or "/code/" in name for name in archive.namelist())


def calibrate_batch_norm(model: nn.Module, n_images: int = 4, size: int = 128) -> None:
    """Set the image trunk's batch-norm statistics from seeded noise images (random weights only).

    Freshly initialised batch norms hold mean 0 / variance 1, under which the random trunk's
    activations shrink about a thousandfold by layer4, so a random "semantic stream" carries almost
    no signal. One pass in training mode over normalised noise gives every layer unit-scale inputs,
    as trained weights do; the result is deterministic (see :func:`cliport.models.weights.calibrate_batch_norm`).
    """
    weights.calibrate_batch_norm(
        model.visual,
        lambda images: model.visual.forward_intermediates(images, intermediates_only=True),
        n_images=n_images,
        size=size,
        seed=RANDOM_SEED,
    )


def build_clip_model(source: str) -> nn.Module:
    """Build the open_clip RN50 model with weights from `source` ("openai", a file path, or "random")."""
    with _quiet_open_clip(expect_random_init=source == "random"):
        import open_clip

    if source == "random":
        with torch.random.fork_rng(devices=[]), _quiet_open_clip(expect_random_init=True):
            torch.manual_seed(RANDOM_SEED)
            model = open_clip.create_model(MODEL_NAME, pretrained=None)
            calibrate_batch_norm(model)
            return model
    if source == "openai":
        cached = _cached_openai_file()
        if cached is not None:
            with _quiet_open_clip():
                return open_clip.create_model(MODEL_NAME, pretrained=cached)
        if not _hub_reachable():
            raise CLIPWeightsUnavailable(
                _offline_help(source, "the weights are not cached and the Hugging Face hub is unreachable.")
            )
        try:
            with _quiet_open_clip():
                return open_clip.create_model(MODEL_NAME, pretrained="openai")
        except Exception as err:  # open_clip raises bare RuntimeErrors for download failures
            raise CLIPWeightsUnavailable(_offline_help(source, str(err))) from err
    path = Path(source).expanduser()
    if not path.is_file():
        raise CLIPWeightsUnavailable(_offline_help(source, "it is neither 'openai', 'random' nor an existing file."))
    if path.suffix in (".pt", ".pth") and _is_torchscript(path):
        try:
            with _quiet_open_clip():
                return open_clip.load_openai_model(str(path), precision="fp32", device="cpu")
        except Exception as err:  # TorchScript and open_clip raise assorted errors for a broken archive
            raise _bad_file(path, f"not a loadable OpenAI TorchScript RN50 ({_first_sentence(err)})") from None
    state = _load_state_dict_file(path)
    # The weights are loaded right below (strictly), so open_clip's "initialized randomly" is not true here.
    with _quiet_open_clip(expect_random_init=True):
        model = open_clip.create_model(MODEL_NAME, pretrained=None)
    _check_architecture(path, state, model.state_dict())
    model.load_state_dict(state, strict=True)
    return model


class FrozenCLIP(FrozenEncoder):
    """A frozen CLIP RN50: image trunk levels (stem, layer1..4) and sentence features, cached per instruction."""

    trunk_channels = TRUNK_CHANNELS
    sentence_dim = SENTENCE_DIM

    def __init__(self, model: nn.Module, source: str) -> None:
        super().__init__()
        self.model = model
        self.source = source
        self._tokenizer = _tokenizer()
        self.register_buffer("mean", torch.tensor(CLIP_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(CLIP_STD).view(1, 3, 1, 1), persistent=False)
        self.freeze()

    def sources(self) -> dict[str, str]:
        return {"clip_weights": self.source}

    def image_module(self) -> nn.Module:
        return self.model.visual

    def instruction_note(self, text: str) -> str | None:
        n_tokens = _count_tokens(self._tokenizer, text)
        if n_tokens > CONTEXT_LENGTH:
            return f"the instruction has {n_tokens} CLIP tokens; CLIP reads the first {CONTEXT_LENGTH}"
        return None

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        x = ((rgb - self.mean) / self.std).to(self.image_dtype())
        return self.model.visual.forward_intermediates(x, intermediates_only=True)["image_intermediates"]

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        for text in texts:
            _warn_if_truncated(text, _count_tokens(self._tokenizer, text))
        return self.model.encode_text(self._tokenizer(texts).to(self.mean.device))


@functools.cache
def _tokenizer() -> Any:
    with _quiet_open_clip():
        import open_clip

        return open_clip.get_tokenizer(MODEL_NAME)


def _count_tokens(tokenizer: Any, text: str) -> int:
    return len(tokenizer.encode(text)) + 2  # + start and end tokens


def instruction_token_count(text: str) -> int:
    """CLIP tokens of an instruction, start and end tokens included; CLIP reads :data:`CONTEXT_LENGTH`."""
    return _count_tokens(_tokenizer(), text)


def _warn_if_truncated(text: str, n_tokens: int) -> None:
    if n_tokens > CONTEXT_LENGTH and text not in _warned_long_instructions:
        _warned_long_instructions.add(text)
        log.warning(
            "instruction has %d CLIP tokens but CLIP reads only %d, the rest is ignored: %r",
            n_tokens,
            CONTEXT_LENGTH,
            text,
        )


def load_clip(source: str) -> FrozenCLIP:
    """Load the frozen CLIP RN50 from `source` ("openai", a weights file, or "random")."""
    return FrozenCLIP(build_clip_model(source), source)
