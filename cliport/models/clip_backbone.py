"""One frozen open_clip model shared by every semantic stream: image trunk features and sentence features.

The model is any name of ``open_clip.list_models()`` (``--semantic-encoder NAME``); the default is
``RN50-quickgelu`` (CLIPort's CLIP RN50). Names are checked before anything is built: an unknown one
raises :class:`UnknownEncoderError` naming the closest known names.

Image trunks (five levels at strides 4, 4, 8, 16, 32, see :class:`FrozenCLIP`):

- open_clip's ResNets (``RN50``, ``RN101``, ``RN50x4``, ... and their ``-quickgelu`` twins): the stem
  and layer1..layer4, as CLIPort uses them.
- open_clip's ViTs (``ViT-B-16``, ``ViT-B-32``, ``ViT-L-14``, ...): the patch tokens of four blocks
  spread evenly through the depth, resampled to the four strides (:meth:`FrozenCLIP._vit_levels`).
- Image towers that come from timm (``ViT-B-16-SigLIP*``, ``convnext_*``, ``EVA*``, ``ViTamin*``, ...)
  are not supported: :class:`UnsupportedEncoderError` says so before the weights are fetched.

Text: the model's own tokenizer (``open_clip.get_tokenizer(name)``) and its context length (77 for the
OpenAI-style models, other values elsewhere). open_clip ships the CLIP BPE tokenizer inside the package;
models whose tokenizer is a Hugging Face one (the SigLIP family, ``*-CLIPA``, ``*-worldwide``,
``roberta-*``, ``xlm-roberta-*``, ``mt5-*``, ``nllb-*``) fetch it from the Hugging Face hub, and the
HF-text-tower models also their text tower's config. Offline they therefore need a Hugging Face cache
(``HF_HOME``) filled on a machine with network; without one, loading fails with one line,
:class:`TokenizerUnavailable`, before any weights are fetched. (SigLIP models are refused for their timm
image tower in any case, see above.)

Weight sources (``clip_weights`` in the agent configs), the same policy for every model:

- a pretrained tag of the model, one of ``open_clip.list_pretrained_tags_by_model(name)`` (``"openai"``
  for the default): taken from the Hugging Face cache when present, otherwise downloaded. Without network
  this fails within seconds with :class:`CLIPWeightsUnavailable`, which lists the offline options.
- a path to a local file: a state dict (``.pt``/``.pth``/``.bin`` or ``.safetensors``) of the model
  (its architecture is checked), or, for the models OpenAI released, OpenAI's own TorchScript file
  (e.g. ``RN50.pt``).
- ``"random"``: a random initialisation, seeded (seed 0) so that reloading a checkpoint reproduces it;
  a ResNet trunk's batch norms are calibrated (:func:`calibrate_batch_norm`), ViTs (LayerNorm only) need
  nothing. Only when asked for explicitly; a failed load never falls back to it.

The input normalisation is the model's preprocessing mean/std: the tag's for a pretrained tag, otherwise
the one all of the model's tags share (open_clip's OpenAI default when they differ or there are none).
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import importlib.util
import json
import logging
import os
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from cliport.errors import UserError
from cliport.models import weights
from cliport.models.encoders import FrozenEncoder

#: The default model (``--semantic-encoder``): CLIPort's CLIP RN50.
MODEL_NAME = "RN50-quickgelu"
# The default model's sentence width and trunk channels (stem, layer1..layer4 at strides 4, 4, 8, 16, 32);
# other models have their own, see FrozenCLIP.trunk_channels and FrozenCLIP.sentence_dim.
SENTENCE_DIM = 1024
TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
RANDOM_SEED = 0
# The default model reads at most this many tokens of an instruction, start and end tokens included; the
# tokenizer cuts the rest off without saying so. Other models: FrozenCLIP.context_length.
CONTEXT_LENGTH = 77
#: The strides the ViT adapter resamples its four chosen blocks' patch tokens to (layer1..layer4).
_VIT_LEVEL_STRIDES = (4, 8, 16, 32)
_RANDOM_INIT_WARNING = "No pretrained weights loaded for model"



class CLIPWeightsUnavailable(UserError, RuntimeError):
    """The requested CLIP weights could not be loaded."""


class UnknownEncoderError(UserError, ValueError):
    """The semantic encoder's name is not an open_clip model with a text tower."""


class UnsupportedEncoderError(UserError, ValueError):
    """The open_clip model exists, but its image tower has no trunk adapter here."""


class TokenizerUnavailable(UserError, RuntimeError):
    """The model's tokenizer (or its Hugging Face text tower's config) cannot be fetched."""


# Offline-help file names of OpenAI's own TorchScript releases, by open_clip model name (without -quickgelu).
_OPENAI_TORCHSCRIPT = {
    "RN50": "RN50.pt",
    "RN101": "RN101.pt",
    "RN50x4": "RN50x4.pt",
    "RN50x16": "RN50x16.pt",
    "RN50x64": "RN50x64.pt",
    "ViT-B-32": "ViT-B-32.pt",
    "ViT-B-16": "ViT-B-16.pt",
    "ViT-L-14": "ViT-L-14.pt",
    "ViT-L-14-336": "ViT-L-14-336px.pt",
}


def _offline_help(source: str, reason: str, model_name: str = MODEL_NAME) -> str:
    tags = _pretrained_tags(model_name)
    torchscript = _OPENAI_TORCHSCRIPT.get(model_name.removesuffix("-quickgelu")) if "openai" in tags else None
    file_kinds = f"OpenAI's {torchscript} (TorchScript) or " if torchscript else ""
    repo = _hf_repo(model_name, source if source in tags else (tags[0] if tags else ""))
    cache = (
        f"  * pre-populate the Hugging Face cache (HF_HOME) with {repo} on a machine with network;\n" if repo else ""
    )
    tag_list = f"pretrained tags of {model_name}: {', '.join(tags)}" if tags else f"{model_name} has no pretrained tags"
    return (
        f"Cannot load CLIP weights '{source}': {reason}\n"
        "Options without network:\n"
        f"  * copy {file_kinds}an open_clip {model_name} state dict "
        "(.pt/.pth/.bin/.safetensors) to this machine and set clip_weights = '/path/to/file';\n"
        f"{cache}"
        "  * for tests and benchmarks only, set clip_weights = 'random' (seeded random initialisation).\n"
        f"({tag_list})"
    )


def _open_clip_config_dir() -> Path | None:
    spec = importlib.util.find_spec("open_clip")
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / "model_configs"


@functools.cache
def _builtin_model_configs() -> dict[str, dict[str, Any]]:
    """open_clip's built-in model configs read straight from its JSON files (no ``import open_clip``: fast)."""
    config_dir = _open_clip_config_dir()
    configs: dict[str, dict[str, Any]] = {}
    for path in sorted(config_dir.glob("*.json")) if config_dir is not None else []:
        cfg = json.loads(path.read_text())
        if all(k in cfg for k in ("embed_dim", "vision_cfg", "text_cfg")):  # open_clip's own criterion
            configs[path.stem] = cfg
    return configs


def model_config(model_name: str) -> dict[str, Any]:
    """open_clip's config of ``model_name``; :class:`UnknownEncoderError` in one line if there is none.

    Fast (well under a second): reads open_clip's model_configs/ directly unless open_clip is already
    imported, in which case its registry (``open_clip.list_models()``, which may hold added configs) is used.
    """
    import sys

    if "open_clip" in sys.modules:
        from open_clip.factory import get_model_config, list_models

        names = list_models()
        cfg = get_model_config(model_name) if model_name in names else None
    else:
        configs = _builtin_model_configs()
        names = list(configs)
        cfg = configs.get(model_name)
    if cfg is None:
        close = difflib.get_close_matches(model_name, names, n=3, cutoff=0.5)
        hint = f"closest: {', '.join(close)}" if close else "see open_clip.list_models()"
        raise UnknownEncoderError(f"unknown semantic encoder {model_name!r}: not an open_clip model name ({hint})")
    if not cfg.get("text_cfg"):
        raise UnknownEncoderError(f"open_clip model {model_name!r} has no text tower; the semantic stream needs one")
    return cfg


def check_model_name(model_name: str) -> None:
    """Raise :class:`UnknownEncoderError` / :class:`UnsupportedEncoderError` (one line each) for a name this
    module cannot build a semantic encoder from; builds nothing."""
    vision = model_config(model_name)["vision_cfg"]
    if vision.get("timm_model_name"):
        raise UnsupportedEncoderError(
            f"semantic encoder {model_name!r} has a timm image tower ({vision['timm_model_name']}); supported are "
            "open_clip's own ResNet (RN50, RN101, RN50x4, ...) and ViT (ViT-B-16, ViT-B-32, ...) towers"
        )


def _pretrained_tags(model_name: str) -> list[str]:
    with _quiet_open_clip():
        import open_clip

    return list(open_clip.list_pretrained_tags_by_model(model_name))


def _hf_repo(model_name: str, tag: str) -> str | None:
    """The Hugging Face repository a pretrained tag's weights come from (None: a URL-only tag)."""
    import open_clip.pretrained

    hub = open_clip.pretrained.get_pretrained_cfg(model_name, tag).get("hf_hub", "")
    # open_clip's form: "org/repo/" (its default file names) or "org/repo/file.bin".
    return os.path.split(hub)[0] or None


def _hf_filenames(model_name: str, tag: str) -> list[str]:
    import open_clip.pretrained

    filename = os.path.split(open_clip.pretrained.get_pretrained_cfg(model_name, tag).get("hf_hub", ""))[1]
    return [filename] if filename else ["open_clip_model.safetensors", "open_clip_pytorch_model.bin"]


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


def _cached_pretrained_file(model_name: str, tag: str) -> str | None:
    """Path of a pretrained tag's weights in the local Hugging Face cache, if they are there."""
    from huggingface_hub import try_to_load_from_cache

    repo_id = _hf_repo(model_name, tag)
    if repo_id is None:
        return None
    for filename in _hf_filenames(model_name, tag):
        found = try_to_load_from_cache(repo_id, filename)
        if isinstance(found, str):
            return found
    return None


def _bad_file(path: Path, reason: str) -> CLIPWeightsUnavailable:
    return CLIPWeightsUnavailable(f"Cannot load CLIP weights from {path}: {reason}")


def _load_state_dict_file(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of a state-dict file; CLIPWeightsUnavailable naming the file if it is not one."""
    return weights.load_state_dict_file(path, _bad_file)


def _check_architecture(
    path: Path,
    state: Mapping[str, torch.Tensor],
    expected: Mapping[str, torch.Tensor],
    model_name: str = MODEL_NAME,
) -> None:
    """CLIPWeightsUnavailable with a short account if ``state`` is not a state dict of ``expected``'s model."""
    weights.check_architecture(path, state, expected, f"open_clip {model_name}", _bad_file)


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


def _create_model(model_name: str, pretrained: str | None = None) -> nn.Module:
    """``open_clip.create_model``; a Hugging Face text tower whose config cannot be fetched is one line."""
    import open_clip

    kwargs: dict[str, Any] = {} if pretrained is not None else {"pretrained_text": False}
    try:
        return open_clip.create_model(model_name, pretrained=pretrained, **kwargs)
    except OSError as err:  # transformers/huggingface_hub: config not cached and the hub unreachable
        hf_model = model_config(model_name)["text_cfg"].get("hf_model_name")
        if not hf_model:
            raise
        raise TokenizerUnavailable(
            f"Cannot build {model_name}: its text tower's config ({hf_model}) comes from the Hugging Face hub, "
            f"which is unreachable and not in the local cache (HF_HOME) ({weights.first_sentence(err)})"
        ) from None


def _set_normalisation(model: nn.Module, model_name: str, tag: str | None) -> nn.Module:
    """Set ``model.visual.image_mean/image_std`` to what its weights expect and return the model.

    A pretrained tag: that tag's preprocessing mean/std. Other sources (a file, "random"): the mean/std
    all of the model's tags share; when they disagree or there are none, what open_clip set (its OpenAI
    default).
    """
    import open_clip.pretrained

    tags = [tag] if tag is not None else _pretrained_tags(model_name)
    cfgs = [open_clip.pretrained.get_pretrained_cfg(model_name, t) for t in tags]
    pairs = {(tuple(c["mean"]), tuple(c["std"])) for c in cfgs if "mean" in c and "std" in c}
    if len(pairs) == 1:
        model.visual.image_mean, model.visual.image_std = pairs.pop()
        preprocess = getattr(model.visual, "preprocess_cfg", None)
        if isinstance(preprocess, dict):
            preprocess.update(mean=model.visual.image_mean, std=model.visual.image_std)
    return model


def build_clip_model(source: str, model_name: str = MODEL_NAME) -> nn.Module:
    """Build open_clip ``model_name`` with weights from ``source``: one of the model's pretrained tags
    ("openai" for the default), a state-dict file, OpenAI's TorchScript file, or "random".

    The name is checked first (:class:`UnknownEncoderError`, :class:`UnsupportedEncoderError`).
    """
    check_model_name(model_name)
    with _quiet_open_clip(expect_random_init=source == "random"):
        import open_clip

    if source == "random":
        with torch.random.fork_rng(devices=[]), _quiet_open_clip(expect_random_init=True):
            torch.manual_seed(RANDOM_SEED)
            model = _create_model(model_name)
            if any(isinstance(m, nn.BatchNorm2d) for m in model.visual.modules()):
                calibrate_batch_norm(model)
        return _set_normalisation(model, model_name, None)
    tags = _pretrained_tags(model_name)
    if source in tags:
        cached = _cached_pretrained_file(model_name, source)
        if cached is not None:
            with _quiet_open_clip():
                return _set_normalisation(_create_model(model_name, cached), model_name, source)
        if not _hub_reachable():
            raise CLIPWeightsUnavailable(
                _offline_help(source, "the weights are not cached and the Hugging Face hub is unreachable.", model_name)
            )
        try:
            with _quiet_open_clip():
                model = open_clip.create_model(model_name, pretrained=source)
        except Exception as err:  # open_clip raises bare RuntimeErrors for download failures
            raise CLIPWeightsUnavailable(_offline_help(source, str(err), model_name)) from err
        return _set_normalisation(model, model_name, source)
    path = Path(source).expanduser()
    if not path.is_file():
        raise CLIPWeightsUnavailable(
            _offline_help(
                source, f"it is neither a pretrained tag of {model_name}, 'random' nor an existing file.", model_name
            )
        )
    if path.suffix in (".pt", ".pth") and _is_torchscript(path):
        if "openai" not in tags:
            raise _bad_file(path, f"a TorchScript file, but OpenAI released no TorchScript {model_name}")
        try:
            with _quiet_open_clip():
                model = open_clip.load_openai_model(str(path), precision="fp32", device="cpu")
        except Exception as err:  # TorchScript and open_clip raise assorted errors for a broken archive
            reason = f"not a loadable OpenAI TorchScript {model_name} ({weights.first_sentence(err)})"
            raise _bad_file(path, reason) from None
        # load_openai_model builds whatever architecture the file holds: check that it is model_name's
        # (against a random model, so open_clip's "initialized randomly" is expected there).
        with _quiet_open_clip(expect_random_init=True):
            expected = _create_model(model_name).state_dict()
        _check_architecture(path, model.state_dict(), expected, model_name)
        return _set_normalisation(model, model_name, "openai")
    state = _load_state_dict_file(path)
    # The weights are loaded right below (strictly), so open_clip's "initialized randomly" is not true here.
    with _quiet_open_clip(expect_random_init=True):
        model = _create_model(model_name)
    _check_architecture(path, state, model.state_dict(), model_name)
    model.load_state_dict(state, strict=True)
    return _set_normalisation(model, model_name, None)


def _vit_block_indices(depth: int) -> tuple[int, int, int, int]:
    """0-based indices of the four blocks the ViT levels come from: the ends of the four quarters of the depth.

    12 blocks -> (2, 5, 8, 11) (blocks 3, 6, 9, 12); 24 -> (5, 11, 17, 23); 32 -> (7, 15, 23, 31).
    """
    return tuple(max(1, (depth * k + 2) // 4) - 1 for k in (1, 2, 3, 4))  # type: ignore[return-value]


def _resized_pos_embed(pos: torch.Tensor, old_grid: tuple[int, int], new_grid: tuple[int, int]) -> torch.Tensor:
    """A ViT's position embeddings (1 + gh * gw, C) for another token grid: the class token's row kept, the
    (gh, gw) grid of the others bilinearly resized to ``new_grid`` -> (1 + new_h * new_w, C). A new tensor;
    the model's parameter is not touched."""
    if tuple(old_grid) == tuple(new_grid):
        return pos
    channels = pos.shape[-1]
    grid = pos[1:].float().reshape(1, old_grid[0], old_grid[1], channels).permute(0, 3, 1, 2)
    grid = F.interpolate(grid, size=new_grid, mode="bilinear", align_corners=False)
    return torch.cat([pos[:1], grid.permute(0, 2, 3, 1).reshape(-1, channels).to(pos.dtype)])


def _resample_to(grid: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(N, C, h, w) -> (N, C, *size): identity, k x k average pooling when (h, w) = k * size, else bilinear."""
    (h, w), (th, tw) = grid.shape[-2:], size
    if (h, w) == (th, tw):
        return grid
    if h % th == 0 and w % tw == 0 and h // th == w // tw:
        return F.avg_pool2d(grid, h // th)
    return F.interpolate(grid, size=size, mode="bilinear", align_corners=False)


def _trunk_channels(visual: nn.Module) -> tuple[int, int, int, int, int]:
    """Channels of the five trunk levels, read from the image tower's modules (no forward pass)."""
    from open_clip.modified_resnet import ModifiedResNet
    from open_clip.transformer import VisionTransformer

    if isinstance(visual, ModifiedResNet):
        layers = (visual.layer1, visual.layer2, visual.layer3, visual.layer4)
        return (visual.conv3.out_channels, *(layer[-1].conv3.out_channels for layer in layers))  # type: ignore[return-value]
    if isinstance(visual, VisionTransformer):
        return (visual.transformer.width,) * 5  # type: ignore[return-value]
    raise UnsupportedEncoderError(f"no trunk adapter for the image tower {type(visual).__name__}")


def _sentence_dim(model: nn.Module) -> int | None:
    """Width of ``encode_text``'s output read from the text tower's modules (None: not readable)."""
    projection = getattr(model, "text_projection", None)
    if isinstance(projection, nn.Linear):
        return projection.out_features
    if isinstance(projection, torch.Tensor):
        return int(projection.shape[-1])
    text = getattr(model, "text", None)  # CustomTextCLIP: a text tower module with its own projection
    if isinstance(getattr(text, "output_dim", None), int):
        return text.output_dim  # type: ignore[union-attr]
    return None


class FrozenCLIP(FrozenEncoder):
    """A frozen open_clip model: five image trunk levels and sentence features, cached per instruction.

    ``trunk_channels`` and ``sentence_dim`` are per instance, read from the model's modules:

    - ResNet towers: the stem and layer1..layer4 of ``forward_intermediates`` (strides 4, 4, 8, 16, 32);
      channels = the stem's last conv and each layer's last bottleneck conv (RN50, RN101:
      64, 256, 512, 1024, 2048; RN50x4: 80, 320, 640, 1280, 2560).
    - ViT towers: five levels of the transformer width (768 for ViT-B) built from patch tokens, see
      :meth:`_vit_levels`.

    ``sentence_dim`` is the text projection's output width (RN50: 1024; RN101, ViT-B-16: 512). Images are
    normalised with the model's ``visual.image_mean/image_std``; sentences use the model's own tokenizer and
    context length (:attr:`context_length`).
    """

    def __init__(self, model: nn.Module, source: str, model_name: str = MODEL_NAME) -> None:
        """``model``: an open_clip CLIP of ``model_name`` (see :func:`build_clip_model`); ``source``: where its
        weights came from (reported by :meth:`sources`)."""
        super().__init__()
        from open_clip.transformer import VisionTransformer

        self.model = model
        self.source = source
        self.model_name = model_name
        self._tokenizer = _tokenizer(model_name)
        self.context_length = int(getattr(self._tokenizer, "context_length", None) or model.context_length)
        visual = model.visual
        self.trunk_channels = _trunk_channels(visual)
        #: 0-based indices of the four blocks the ViT levels come from; None for a ResNet tower.
        self.vit_blocks = (
            _vit_block_indices(len(visual.transformer.resblocks)) if isinstance(visual, VisionTransformer) else None
        )
        sentence_dim = _sentence_dim(model)
        if sentence_dim is None:  # not readable from the modules: one tiny pass
            with torch.no_grad():
                sentence_dim = int(model.encode_text(self._tokenizer(["a"])).shape[-1])
        self.sentence_dim = sentence_dim
        mean = getattr(visual, "image_mean", None) or CLIP_MEAN
        std = getattr(visual, "image_std", None) or CLIP_STD
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1), persistent=False)
        self.freeze()

    def sources(self) -> dict[str, str]:
        return {"clip_weights": self.source}

    def image_module(self) -> nn.Module:
        return self.model.visual

    def instruction_note(self, text: str) -> str | None:
        n_tokens = _count_tokens(self._tokenizer, text)
        if n_tokens > self.context_length:
            return f"the instruction has {n_tokens} CLIP tokens; CLIP reads the first {self.context_length}"
        return None

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        x = ((rgb - self.mean) / self.std).to(self.image_dtype())
        if self.vit_blocks is not None:
            return self._vit_levels(x)
        return self.model.visual.forward_intermediates(x, intermediates_only=True)["image_intermediates"]

    def _vit_levels(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Five trunk levels of a ViT tower, parameter-free, from normalised images (N, 3, H, W).

        1. Token grid: (gh, gw) = (H / p, W / p) for the patch size p (rounded, and the image bilinearly
           resized to (gh * p, gw * p) when p does not divide H or W, e.g. p = 14). The ViT runs on the
           image at its own size: the position embeddings' grid (224 / p squared) is bilinearly resized to
           (gh, gw), the class token's embedding kept as it is (:func:`_resized_pos_embed`; the model's
           weights are not changed).
        2. Blocks: the patch tokens (class token dropped, no final LayerNorm) after the four blocks ending
           the four quarters of the depth (:func:`_vit_block_indices`: blocks 3, 6, 9, 12 of ViT-B's 12),
           each reshaped to (N, C, gh, gw). Evenly spaced blocks go from local, early features to the
           last block's semantic ones that CLIP's embedding is read from, the way a ResNet's layer1..4 do
           (and as DPT reads ViT-B).
        3. Strides: the i-th block is resampled to stride (4, 8, 16, 32)[i], i.e. to (H / s, W / s):
           identity where the grid already has that size, k x k average pooling where it is k times
           larger, bilinear interpolation otherwise (p = 16: x4 and x2 bilinear up, identity, 2 x 2
           average pool).
        4. Levels: [stem, layer1, layer2, layer3, layer4] = [b1 at /4, b1 at /4, b2 at /8, b3 at /16,
           b4 at /32]: the stem is the first block's stride-4 map (the same tensor as layer1).

        Returns five (N, width, H / s, W / s) maps for the strides (4, 4, 8, 16, 32).
        """
        visual = self.model.visual
        assert self.vit_blocks is not None
        n, _, h, w = x.shape
        ph, pw = visual.patch_size
        gh, gw = max(1, round(h / ph)), max(1, round(w / pw))
        if (gh * ph, gw * pw) != (h, w):
            x = F.interpolate(x, size=(gh * ph, gw * pw), mode="bilinear", align_corners=False)
        tokens = visual.conv1(x).flatten(2).transpose(1, 2)  # (N, gh * gw, C)
        cls = visual.class_embedding.to(tokens.dtype).view(1, 1, -1).expand(n, 1, -1)
        pos = _resized_pos_embed(visual.positional_embedding, visual.grid_size, (gh, gw)).to(tokens.dtype)
        tokens = visual.ln_pre(visual.patch_dropout(torch.cat([cls, tokens], dim=1) + pos))
        _, blocks = visual.transformer.forward_intermediates(tokens, indices=list(self.vit_blocks), stop_early=True)
        grids = [b[:, 1:].transpose(1, 2).reshape(n, -1, gh, gw) for b in blocks]
        levels = [_resample_to(g, (h // s, w // s)) for g, s in zip(grids, _VIT_LEVEL_STRIDES, strict=True)]
        return [levels[0], *levels]

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        return self.model.encode_text(self._tokenizer(texts).to(self.mean.device))


@functools.cache
def _tokenizer(model_name: str = MODEL_NAME) -> Any:
    """The model's tokenizer; :class:`TokenizerUnavailable` in one line when it cannot be fetched."""
    with _quiet_open_clip():
        import open_clip

        try:
            return open_clip.get_tokenizer(model_name)
        except Exception as err:  # transformers/huggingface_hub raise OSError, ValueError, ... offline
            raise TokenizerUnavailable(
                f"Cannot load the tokenizer of {model_name}: it comes from the Hugging Face hub, which is "
                f"unreachable and not in the local cache (HF_HOME) ({weights.first_sentence(err)}); fill the cache "
                "on a machine with network, or choose a model with open_clip's own tokenizer (e.g. RN50-quickgelu)"
            ) from None


def _count_tokens(tokenizer: Any, text: str) -> int:
    """Tokens of ``text`` with the model's special tokens (CLIP BPE: start and end)."""
    if hasattr(tokenizer, "encode"):  # open_clip's SimpleTokenizer
        return len(tokenizer.encode(text)) + 2  # + start and end tokens
    return len(tokenizer.tokenizer(text)["input_ids"])  # a wrapped Hugging Face tokenizer adds its own


def instruction_token_count(text: str, model_name: str = MODEL_NAME) -> int:
    """Tokens of an instruction for ``model_name``, special tokens included; the default reads
    :data:`CONTEXT_LENGTH`, others :attr:`FrozenCLIP.context_length`."""
    return _count_tokens(_tokenizer(model_name), text)


def load_clip(source: str, model_name: str = MODEL_NAME) -> FrozenCLIP:
    """Load frozen open_clip ``model_name`` (default RN50-quickgelu) from ``source``: a pretrained tag of
    the model ("openai" for the default), a weights file, or "random".

    Checks in this order, each failing in one line before the next is tried: the name
    (:class:`UnknownEncoderError`, :class:`UnsupportedEncoderError`), the tokenizer
    (:class:`TokenizerUnavailable`), then the weights (:class:`CLIPWeightsUnavailable`).
    """
    check_model_name(model_name)
    _tokenizer(model_name)
    return FrozenCLIP(build_clip_model(source, model_name), source, model_name)
