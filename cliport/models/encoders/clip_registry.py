"""open_clip model names: which models a semantic encoder can be built from, checked before anything is built.

The model is any name of ``open_clip.list_models()`` (``--semantic-encoder NAME``); the default is
``RN50-quickgelu`` (CLIPort's CLIP RN50). An unknown name raises :class:`UnknownEncoderError` naming the
closest known names; a model whose image tower comes from timm (``ViT-B-16-SigLIP*``, ``convnext_*``,
``EVA*``, ``ViTamin*``, ...) raises :class:`UnsupportedEncoderError` before any weights are fetched. Also
keeps open_clip's log lines quiet (:func:`quiet_open_clip`).
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import importlib.util
import json
import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cliport.errors import UserError

#: The default model (``--semantic-encoder``): CLIPort's CLIP RN50.
MODEL_NAME = "RN50-quickgelu"
_RANDOM_INIT_WARNING = "No pretrained weights loaded for model"


class UnknownEncoderError(UserError, ValueError):
    """The semantic encoder's name is not an open_clip model with a text tower."""


class UnsupportedEncoderError(UserError, ValueError):
    """The open_clip model exists, but its image tower has no trunk adapter here."""


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


def pretrained_tags(model_name: str) -> list[str]:
    with quiet_open_clip():
        import open_clip

    return list(open_clip.list_pretrained_tags_by_model(model_name))


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
def quiet_open_clip(expect_random_init: bool = False) -> Iterator[None]:
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
