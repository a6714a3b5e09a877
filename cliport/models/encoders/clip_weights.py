"""Weights of the frozen open_clip model: pretrained tags, local files and a seeded random initialisation.

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

import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from cliport.errors import UserError
from cliport.models.encoders import weights
from cliport.models.encoders.clip_registry import (
    MODEL_NAME,
    check_model_name,
    import_open_clip,
    model_config,
    pretrained_tags,
    quiet_open_clip,
)
from cliport.models.encoders.clip_tokenizer import TokenizerUnavailable
from cliport.utils import hub

RANDOM_SEED = 0


class CLIPWeightsUnavailable(UserError, RuntimeError):
    """The requested CLIP weights could not be loaded."""


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
    tags = pretrained_tags(model_name)
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


def _hub_reachable(timeout_s: float = 3.0) -> bool:
    """Whether the Hugging Face hub answers a TCP connection within `timeout_s` seconds (False if HF_HUB_OFFLINE)."""
    return hub.hf_hub_reachable(timeout_s)


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


def published_weights_available(tag: str = "openai", model_name: str = MODEL_NAME) -> bool:
    """Whether ``tag``'s weights can be had now: in the Hugging Face cache, or the hub answers (never for a model
    without that tag, such as cliport's own configs)."""
    if tag not in pretrained_tags(model_name):
        return False
    return _cached_pretrained_file(model_name, tag) is not None or _hub_reachable()


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


#: The safetensors metadata key naming the open_clip model a weights file holds (``cliport-pretrain`` writes it).
MODEL_NAME_KEY = "open_clip_model"


def _written_for(path: Path) -> str | None:
    """The model a safetensors weights file says it holds (:data:`MODEL_NAME_KEY`), or None (not said, not one)."""
    if path.suffix != ".safetensors":
        return None
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="pt") as f:
            return (f.metadata() or {}).get(MODEL_NAME_KEY)
    except (SafetensorError, OSError):
        return None


def _is_torchscript(path: Path) -> bool:
    """TorchScript archives (OpenAI's RN50.pt) hold compiled code next to the tensors."""
    if not zipfile.is_zipfile(path):
        return False
    with zipfile.ZipFile(path) as archive:
        return any(name.endswith("constants.pkl") or "/code/" in name for name in archive.namelist())


def calibrate_batch_norm(model: Any, n_images: int = 4, size: int = 128) -> None:
    """Set the image trunk's batch-norm statistics from seeded noise images (random weights only).

    Freshly initialised batch norms hold mean 0 / variance 1, under which the random trunk's
    activations shrink about a thousandfold by layer4, so a random "semantic stream" carries almost
    no signal. One pass in training mode over normalised noise gives every layer unit-scale inputs,
    as trained weights do; the result is deterministic (see
    :func:`cliport.models.encoders.weights.calibrate_batch_norm`).
    """
    weights.calibrate_batch_norm(
        model.visual,
        lambda images: model.visual.forward_intermediates(images, intermediates_only=True),
        n_images=n_images,
        size=size,
        seed=RANDOM_SEED,
    )


def _create_model(model_name: str, pretrained: str | None = None) -> Any:
    """``open_clip.create_model``; a Hugging Face text tower whose config cannot be fetched is one line."""
    open_clip = import_open_clip()

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


def _set_normalisation(model: Any, model_name: str, tag: str | None) -> nn.Module:
    """Set ``model.visual.image_mean/image_std`` to what its weights expect and return the model.

    A pretrained tag: that tag's preprocessing mean/std. Other sources (a file, "random"): the mean/std
    all of the model's tags share; when they disagree or there are none, what open_clip set (its OpenAI
    default).
    """
    import open_clip.pretrained

    tags = [tag] if tag is not None else pretrained_tags(model_name)
    cfgs = [open_clip.pretrained.get_pretrained_cfg(model_name, t) for t in tags]
    pairs = {(tuple(c["mean"]), tuple(c["std"])) for c in cfgs if "mean" in c and "std" in c}
    if len(pairs) == 1:
        model.visual.image_mean, model.visual.image_std = pairs.pop()
        preprocess = getattr(model.visual, "preprocess_cfg", None)
        if isinstance(preprocess, dict):
            preprocess.update(mean=model.visual.image_mean, std=model.visual.image_std)
    return model


def create_clip_model(model_name: str, seed: int) -> Any:
    """A fresh open_clip ``model_name``: open_clip's initialisation under ``torch.manual_seed(seed)`` (the global
    random state is left as it was), the input normalisation set as for a weights file of the model. What
    ``"random"`` starts from (before its batch-norm calibration) and what ``cliport-pretrain`` trains."""
    check_model_name(model_name)
    with torch.random.fork_rng(devices=[]), quiet_open_clip(expect_random_init=True):
        torch.manual_seed(seed)
        model = _create_model(model_name)
    return _set_normalisation(model, model_name, None)


def build_clip_model(source: str, model_name: str = MODEL_NAME) -> nn.Module:
    """Build open_clip ``model_name`` with weights from ``source``: one of the model's pretrained tags
    ("openai" for the default), a state-dict file, OpenAI's TorchScript file, or "random".

    The name is checked first (:class:`UnknownEncoderError`, :class:`UnsupportedEncoderError`).
    """
    check_model_name(model_name)
    open_clip = import_open_clip()

    if source == "random":
        model = create_clip_model(model_name, RANDOM_SEED)
        if any(isinstance(m, nn.BatchNorm2d) for m in model.visual.modules()):
            with torch.random.fork_rng(devices=[]):
                calibrate_batch_norm(model)
        return model
    tags = pretrained_tags(model_name)
    if source in tags:
        cached = _cached_pretrained_file(model_name, source)
        if cached is not None:
            with quiet_open_clip():
                return _set_normalisation(_create_model(model_name, cached), model_name, source)
        if not _hub_reachable():
            raise CLIPWeightsUnavailable(
                _offline_help(source, "the weights are not cached and the Hugging Face hub is unreachable.", model_name)
            )
        try:
            with quiet_open_clip():
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
            with quiet_open_clip():
                model = open_clip.load_openai_model(str(path), precision="fp32", device="cpu")
        except Exception as err:  # TorchScript and open_clip raise assorted errors for a broken archive
            reason = f"not a loadable OpenAI TorchScript {model_name} ({weights.first_sentence(err)})"
            raise _bad_file(path, reason) from None
        # load_openai_model builds whatever architecture the file holds: check that it is model_name's
        # (against a random model, so open_clip's "initialized randomly" is expected there).
        with quiet_open_clip(expect_random_init=True):
            expected = _create_model(model_name).state_dict()
        _check_architecture(path, model.state_dict(), expected, model_name)
        return _set_normalisation(model, model_name, "openai")
    state = _load_state_dict_file(path)
    # The weights are loaded right below (strictly), so open_clip's "initialized randomly" is not true here.
    with quiet_open_clip(expect_random_init=True):
        model = _create_model(model_name)
    written_for = _written_for(path)
    if written_for is not None and written_for != model_name:
        reason = f"its metadata says it holds {written_for} weights, not {model_name}'s"
        raise _bad_file(path, f"{reason} (semantic encoder {written_for}?)")
    _check_architecture(path, state, model.state_dict(), model_name)
    model.load_state_dict(state, strict=True)
    return _set_normalisation(model, model_name, None)
