"""The settings of ``cliport-pretrain``: :class:`PretrainConfig`, defaults in ``configs/pretrain.toml``, whose
``[cpu]`` or ``[cuda]`` table (chosen by ``device``) goes over the values above it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from cliport.env.config import check_renderer
from cliport.errors import ConfigError
from cliport.utils.config import defaults_file, from_dict, read_defaults

DEVICES = ("cpu", "cuda")


@dataclass
class PretrainConfig:
    """Contrastive image-text pretraining of a semantic encoder on rendered crops; defaults in configs/pretrain.toml.

    Args:
        device: cpu or cuda; picks the [cpu] / [cuda] table of configs/pretrain.toml.
        semantic_encoder: the open_clip model to pretrain, the name an agent's --semantic-encoder then gives:
            cliport-RN-tiny (a CPU's), cliport-RN-small, RN50-quickgelu (CLIPort's size, for a GPU), ...
        out_dir: where the weights (open_clip_model.safetensors), their open_clip config and the run's record go.
        cache_dir: the rendered crops (train and held-out probe scenes), shared by runs with the same settings.
        train_scenes: scenes rendered for training (about 14 crops each).
        probe_scenes: held-out scenes for the probe (never trained on).
        crop_px: side of a stored crop in pixels; the model reads crops at its own image size.
        camera_scale: the workcell cameras' resolution for the top-down map.
        renderer: auto, egl or cpu (TinyRenderer); the cache records it, pixels differ between them.
        render_workers: simulator processes rendering the crops.
        steps: optimiser steps.
        batch_size: crops (and captions) per step.
        lr: AdamW peak learning rate, reached after warmup_steps and decayed to 0 along a cosine.
        weight_decay: AdamW weight decay of weight matrices (not norms, biases, embeddings, the temperature).
        warmup_steps: steps of linear learning-rate warm-up.
        dense_weight: weight of the dense objective (each pixel of whole scenes' maps against the captions of
            their things, :mod:`cliport.pretrain.dense`) beside the contrastive loss; 0 trains without it.
        dense_scenes: scene windows per step for the dense objective.
        dense_scale: the scale the dense objective reads the maps at: an agent's ``similarity_scale``.
        seed: the model's initial weights and every batch.
        log_every: steps between logged rows (metrics.json).
        save_every: steps between resumable saves (state.pt, atomic).
    """

    device: str
    semantic_encoder: str
    out_dir: str
    cache_dir: str
    train_scenes: int
    probe_scenes: int
    crop_px: int
    camera_scale: float
    renderer: str
    render_workers: int
    steps: int
    batch_size: int
    lr: float
    weight_decay: float
    warmup_steps: int
    dense_weight: float
    dense_scenes: int
    dense_scale: float
    seed: int
    log_every: int
    save_every: int

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def validate(self) -> None:
        """ConfigError in one line for a value no run can use (the model name is checked too)."""
        from cliport.models.encoders.clip_registry import check_model_name

        if self.device not in DEVICES:
            raise ConfigError(f"device must be one of {', '.join(DEVICES)}, got {self.device!r}")
        for name in ("train_scenes", "probe_scenes", "steps", "batch_size", "log_every", "save_every", "dense_scenes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be at least 1, got {getattr(self, name)}")
        for name in ("warmup_steps", "render_workers"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be at least 0, got {getattr(self, name)}")
        if self.batch_size < 2:
            raise ConfigError(f"batch_size must be at least 2 (a batch's negatives), got {self.batch_size}")
        if self.crop_px < 16:
            raise ConfigError(f"crop_px must be at least 16, got {self.crop_px}")
        if self.camera_scale <= 0:
            raise ConfigError(f"camera_scale must be positive, got {self.camera_scale}")
        if self.lr <= 0 or self.weight_decay < 0:
            raise ConfigError(f"lr must be > 0 and weight_decay >= 0, got {self.lr} and {self.weight_decay}")
        if self.dense_weight < 0 or self.dense_scale <= 0:
            raise ConfigError(
                f"dense_weight must be >= 0 and dense_scale > 0, got {self.dense_weight} and {self.dense_scale}"
            )
        check_renderer(self.renderer)
        check_model_name(self.semantic_encoder)


def load_config(overrides: dict[str, Any] | None = None) -> PretrainConfig:
    """configs/pretrain.toml with its ``device`` table over it, then ``overrides`` (flags), checked."""
    overrides = dict(overrides or {})
    table = read_defaults("pretrain")
    device = overrides.get("device", table.get("device"))
    if device not in DEVICES:
        raise ConfigError(f"device must be one of {', '.join(DEVICES)}, got {device!r}")
    base = {k: v for k, v in table.items() if k not in DEVICES}
    config = from_dict(PretrainConfig, {**base, **table[device], **overrides}, f"{defaults_file('pretrain')} + flags")
    config.validate()
    return config
