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

import logging
import os
import socket
import zipfile
from pathlib import Path

import torch
from torch import nn

from cliport.errors import UserError

MODEL_NAME = "RN50-quickgelu"
SENTENCE_DIM = 1024
# Channels of the trunk's intermediate features: stem, layer1..layer4 (strides 4, 4, 8, 16, 32).
TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
RANDOM_SEED = 0
_HUB_HOST = ("huggingface.co", 443)

log = logging.getLogger(__name__)


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


def _hub_reachable(timeout_s: float = 3.0) -> bool:
    """Whether the Hugging Face hub answers a TCP connection within `timeout_s` seconds."""
    if os.environ.get("HF_HUB_OFFLINE", "0") not in ("0", "", "false", "False"):
        return False
    try:
        with socket.create_connection(_HUB_HOST, timeout=timeout_s):
            return True
    except OSError:
        return False


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


def _load_state_dict_file(path: Path) -> dict[str, torch.Tensor]:
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return load_file(str(path))
    state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    return {k.removeprefix("module."): v for k, v in state.items()}


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
    as trained weights do; the result is deterministic.
    """
    norms = [m for m in model.visual.modules() if isinstance(m, nn.BatchNorm2d)]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average: one batch sets the statistics exactly
    generator = torch.Generator().manual_seed(RANDOM_SEED)
    images = torch.randn(n_images, 3, size, size, generator=generator)
    model.visual.train()
    with torch.no_grad():
        model.visual.forward_intermediates(images, intermediates_only=True)
    model.visual.eval()
    for m in norms:
        m.momentum = 0.1


def build_clip_model(source: str) -> nn.Module:
    """Build the open_clip RN50 model with weights from `source` ("openai", a file path, or "random")."""
    import open_clip

    if source == "random":
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(RANDOM_SEED)
            model = open_clip.create_model(MODEL_NAME, pretrained=None)
            calibrate_batch_norm(model)
            return model
    if source == "openai":
        cached = _cached_openai_file()
        if cached is not None:
            return open_clip.create_model(MODEL_NAME, pretrained=cached)
        if not _hub_reachable():
            raise CLIPWeightsUnavailable(
                _offline_help(source, "the weights are not cached and the Hugging Face hub is unreachable.")
            )
        try:
            return open_clip.create_model(MODEL_NAME, pretrained="openai")
        except Exception as err:  # open_clip raises bare RuntimeErrors for download failures
            raise CLIPWeightsUnavailable(_offline_help(source, str(err))) from err
    path = Path(source).expanduser()
    if not path.is_file():
        raise CLIPWeightsUnavailable(_offline_help(source, "it is neither 'openai', 'random' nor an existing file."))
    if path.suffix in (".pt", ".pth") and _is_torchscript(path):
        return open_clip.load_openai_model(str(path), precision="fp32", device="cpu")
    model = open_clip.create_model(MODEL_NAME, pretrained=None)
    model.load_state_dict(_load_state_dict_file(path), strict=True)
    return model


class FrozenCLIP(nn.Module):
    """A frozen CLIP RN50: always in eval mode, no gradients, sentence features cached per instruction."""

    def __init__(self, model: nn.Module, source: str) -> None:
        super().__init__()
        self.model = model
        self.source = source
        self.model.requires_grad_(False)
        self.model.eval()
        self._sentence_cache: dict[str, torch.Tensor] = {}
        import open_clip

        self._tokenizer = open_clip.get_tokenizer(MODEL_NAME)
        self.register_buffer("mean", torch.tensor(CLIP_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(CLIP_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True) -> FrozenCLIP:
        """Stay in eval mode whatever is asked, so batch-norm statistics never drift."""
        return super().train(False)

    @torch.no_grad()
    def image_features(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """Trunk features of RGB images with values in [0, 1].

        (N, 3, H, W) -> [stem (N, 64, H/4, W/4), layer1 (N, 256, H/4, W/4), layer2 (N, 512, H/8, W/8),
        layer3 (N, 1024, H/16, W/16), layer4 (N, 2048, H/32, W/32)].
        """
        x = (rgb - self.mean) / self.std
        dtype = next(self.model.visual.parameters()).dtype
        out = self.model.visual.forward_intermediates(x.to(dtype), intermediates_only=True)
        return [f.float() for f in out["image_intermediates"]]

    @torch.no_grad()
    def sentence_features(self, texts: list[str]) -> torch.Tensor:
        """Sentence vectors of `texts`, (B,) -> (B, 1024), each string encoded once and cached."""
        device = self.mean.device
        missing = sorted({t for t in texts if t not in self._sentence_cache})
        if missing:
            tokens = self._tokenizer(missing).to(device)
            feats = self.model.encode_text(tokens).float()
            for text, feat in zip(missing, feats, strict=True):
                self._sentence_cache[text] = feat
        out = torch.stack([self._sentence_cache[t] for t in texts])
        return out.to(device)

    def _apply(self, fn, recurse: bool = True):  # type: ignore[no-untyped-def]
        self._sentence_cache.clear()
        return super()._apply(fn, recurse)


def load_clip(source: str) -> FrozenCLIP:
    """Load the frozen CLIP RN50 from `source` ("openai", a weights file, or "random")."""
    return FrozenCLIP(build_clip_model(source), source)
