"""open_clip model names: which models a semantic encoder can be built from, checked before anything is built.

The model is any name of ``open_clip.list_models()`` (``--semantic-encoder NAME``); the default is
``RN50-quickgelu`` (CLIPort's CLIP RN50). An unknown name raises :class:`UnknownEncoderError` naming the
closest known names; a model whose image tower comes from timm (``ViT-B-16-SigLIP*``, ``convnext_*``,
``EVA*``, ``ViTamin*``, ...) raises :class:`UnsupportedEncoderError` before any weights are fetched. Also
keeps open_clip's log lines quiet (:func:`quiet_open_clip`).

Besides open_clip's own models, cliport ships small CLIP configs in open_clip's JSON format
(``model_configs/``: ``cliport-RN-tiny``, ``cliport-RN-small``), ResNet and text-transformer CLIPs narrow enough
to pretrain on a CPU (``cliport-pretrain``). They have no published weights: ``random``, or a file written by
``cliport-pretrain``. :func:`import_open_clip` registers them with open_clip, so that every name this module
accepts is one ``open_clip.create_model`` and ``open_clip.get_tokenizer`` know.
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
#: cliport's own open_clip model configs (one JSON file per model, named by the file), see the module docstring.
CLIPORT_CONFIG_DIR = Path(__file__).with_name("model_configs")
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


def _read_configs(config_dir: Path | None) -> dict[str, dict[str, Any]]:
    """The model configs in a folder of open_clip JSON files, by file stem (open_clip's criterion for a config)."""
    configs: dict[str, dict[str, Any]] = {}
    for path in sorted(config_dir.glob("*.json")) if config_dir is not None else []:
        cfg = json.loads(path.read_text())
        if all(k in cfg for k in ("embed_dim", "vision_cfg", "text_cfg")):
            configs[path.stem] = cfg
    return configs


@functools.cache
def _builtin_model_configs() -> dict[str, dict[str, Any]]:
    """open_clip's built-in model configs and cliport's (:data:`CLIPORT_CONFIG_DIR`), read straight from their JSON
    files (no ``import open_clip``: fast)."""
    return {**_read_configs(_open_clip_config_dir()), **cliport_model_configs()}


@functools.cache
def cliport_model_configs() -> dict[str, dict[str, Any]]:
    """cliport's own open_clip model configs by name (``cliport-RN-tiny``, ...): :data:`CLIPORT_CONFIG_DIR`."""
    return _read_configs(CLIPORT_CONFIG_DIR)


def import_open_clip() -> Any:
    """``open_clip``, imported with its log kept quiet, with cliport's model configs registered (once per process):
    every module here gets open_clip through this function before it builds a model or a tokenizer by name."""
    with quiet_open_clip():
        import open_clip

    if not set(cliport_model_configs()) <= set(open_clip.list_models()):
        open_clip.add_model_config(CLIPORT_CONFIG_DIR)
    return open_clip


def model_config(model_name: str) -> dict[str, Any]:
    """open_clip's config of ``model_name``; :class:`UnknownEncoderError` in one line if there is none.

    Fast (well under a second): reads open_clip's model_configs/ directly unless open_clip is already
    imported, in which case its registry (``open_clip.list_models()``, which may hold added configs) is used.
    """
    import sys

    if "open_clip" in sys.modules:
        open_clip = import_open_clip()  # already imported: this only makes sure cliport's configs are registered
        names = open_clip.list_models()
        cfg = open_clip.get_model_config(model_name) if model_name in names else None
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
    """The model's published weight tags (``["openai", "yfcc15m", ...]`` for RN50; none for cliport's configs)."""
    return list(import_open_clip().list_pretrained_tags_by_model(model_name))


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
