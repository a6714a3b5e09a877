"""The pretraining run: render the crops once, train the encoders with the contrastive loss, write the weights in
open_clip's format, and probe random against pretrained weights.

A run lives in ``out_dir``: ``config.json`` (its resolved settings), ``state.pt`` (model, optimiser, step and
the logged rows, written atomically every ``save_every`` steps: a re-run resumes there and, batches being a function
of the seed and the step, goes on as the first would have), ``metrics.json``, and at the end the open_clip-format
weights (:mod:`cliport.pretrain.checkpoint`) and ``pretrain.json``. The image and text towers are trained from
open_clip's initialisation (seeded), with AdamW (CLIP's betas and epsilon), a linear warm-up and a cosine decay,
and CLIP's learnable temperature (clamped at 100).
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

import torch
from tqdm import tqdm

from cliport.errors import ConfigError, RunDirError
from cliport.models.encoders.clip_tokenizer import load_tokenizer
from cliport.models.encoders.clip_weights import create_clip_model
from cliport.pretrain.batches import CaptionedCrops
from cliport.pretrain.cache import load_crops, load_scene_maps, render_cache
from cliport.pretrain.checkpoint import RECORD_FILE, STATE_FILE, load_state, save_open_clip, state_tensors
from cliport.pretrain.config import PretrainConfig
from cliport.pretrain.dense import SceneBatch, dense_loss, pixel_logits, step_scene_batch
from cliport.pretrain.loss import MAX_LOGIT_SCALE, contrastive_loss, retrieval_accuracy
from cliport.pretrain.probe import image_size, normalise, probe_weights
from cliport.utils.files import read_json, save_torch, write_json
from cliport.utils.machine import measurement_environment

#: Settings a run may change when it is resumed (the others would make its state another run's).
RESUMABLE_CHANGES = {"steps", "log_every", "save_every", "render_workers", "device", "out_dir"}


def learning_rate(config: PretrainConfig, step: int) -> float:
    """The rate of step ``step`` (0-based): linear warm-up to ``lr``, then a cosine to 0 at ``steps``."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    span = max(1, config.steps - config.warmup_steps)
    return config.lr * 0.5 * (1 + math.cos(math.pi * min(1.0, (step - config.warmup_steps) / span)))


def make_optimizer(model: torch.nn.Module, config: PretrainConfig) -> torch.optim.AdamW:
    """AdamW with CLIP's betas (0.9, 0.98) and epsilon 1e-6; weight decay on weight matrices only."""
    decay: list[torch.nn.Parameter] = []
    no_decay: list[torch.nn.Parameter] = []
    for name, param in model.named_parameters():
        embedding = "embedding" in name or name == "logit_scale"
        (decay if param.ndim >= 2 and not embedding else no_decay).append(param)
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=config.lr, betas=(0.9, 0.98), eps=1e-6)


def check_device(device: str) -> str:
    """``device`` if it can be used here; ConfigError in one line otherwise."""
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device cuda was asked for, but torch sees no CUDA device here: pass --device cpu")
    return device


def _check_resumable(config: PretrainConfig) -> None:
    path = os.path.join(config.out_dir, "config.json")
    if not os.path.exists(path):
        return
    saved = read_json(path)
    changed = sorted(k for k, v in config.to_dict().items() if k not in RESUMABLE_CHANGES and saved.get(k) != v)
    if changed:
        raise RunDirError(
            f"{config.out_dir} holds a pretraining run with other settings ({', '.join(changed)}): "
            "pass another --out-dir, or delete that folder"
        )


class TextEncoder:
    """Encodes a batch's captions, each distinct sentence once (a batch repeats its small vocabulary often)."""

    def __init__(self, model: Any, model_name: str, device: str) -> None:
        self.model, self.device = model, device
        self.tokenizer = load_tokenizer(model_name)
        self._tokens: dict[str, torch.Tensor] = {}

    def __call__(self, captions: list[str]) -> torch.Tensor:
        """(B,) captions -> (B, D) L2-normalised features, with gradients."""
        distinct = list(dict.fromkeys(captions))
        missing = [c for c in distinct if c not in self._tokens]
        if missing:
            for caption, tokens in zip(missing, self.tokenizer(missing), strict=True):
                self._tokens[caption] = tokens
        tokens = torch.stack([self._tokens[c] for c in distinct]).to(self.device)
        features = self.model.encode_text(tokens, normalize=True)
        where = {c: i for i, c in enumerate(distinct)}
        return features[torch.tensor([where[c] for c in captions], device=self.device)]


def train_step(
    model: Any,
    text: TextEncoder,
    batch: Any,
    optimizer: torch.optim.Optimizer,
    device: str,
    scenes: SceneBatch | None = None,
    dense_weight: float = 0.0,
) -> dict[str, float]:
    """One optimiser step on ``batch`` (:class:`~cliport.pretrain.batches.Batch`), and with ``scenes`` the dense
    objective weighted ``dense_weight``; its losses and in-batch accuracy."""
    images = normalise(model, batch.images.to(device))
    image_features = model.encode_image(images, normalize=True)
    text_features = text(batch.captions)
    positives = batch.positives.to(device)
    loss = contrastive_loss(image_features, text_features, model.logit_scale, positives)
    logged: dict[str, float] = {}
    if scenes is not None:
        labels = scenes.labels.to(device)
        size = (labels.shape[-2], labels.shape[-1])
        images = normalise(model, scenes.images.to(device))
        logits = pixel_logits(model.visual, images, text(scenes.captions), model.logit_scale, size)
        dense = dense_loss(logits, labels, scenes.positives.to(device))
        loss = loss + dense_weight * dense
        logged["dense_loss"] = float(dense.detach())
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    with torch.no_grad():
        model.logit_scale.clamp_(0, MAX_LOGIT_SCALE)
        accuracy = retrieval_accuracy(image_features, text_features, positives)
        scale = float(model.logit_scale.exp())
    return {"loss": float(loss.detach()), **logged, "accuracy": accuracy, "logit_scale": scale}


def pretrain(config: PretrainConfig, progress: bool = True, probe: bool = True) -> dict[str, Any]:
    """Run (or resume, or find finished) the pretraining ``config`` describes; returns the run's record
    (``pretrain.json``): settings, steps, seconds, the weights file, and the probe of random and pretrained weights."""
    config.validate()
    device = check_device(config.device)
    _check_resumable(config)
    os.makedirs(config.out_dir, exist_ok=True)
    write_json(os.path.join(config.out_dir, "config.json"), config.to_dict())
    start = time.perf_counter()
    rendered = render_cache(
        config.cache_dir,
        {"train": config.train_scenes, "probe": config.probe_scenes},
        config.crop_px,
        config.camera_scale,
        config.renderer,
        config.render_workers,
        progress,
    )
    render_s = time.perf_counter() - start
    train_crops = load_crops(config.cache_dir, "train", config.train_scenes)
    crops = CaptionedCrops(train_crops, image_size(config.semantic_encoder))
    maps = load_scene_maps(config.cache_dir, "train", config.train_scenes) if config.dense_weight > 0 else None
    model = create_clip_model(config.semantic_encoder, config.seed).to(device)
    optimizer = make_optimizer(model, config)
    state_path = os.path.join(config.out_dir, STATE_FILE)
    step, rows, trained_s = 0, [], 0.0
    if os.path.exists(state_path):
        state = load_state(state_path)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step, rows, trained_s = int(state["step"]), list(state.get("rows", [])), float(state.get("trained_s", 0.0))
    model.train()
    text = TextEncoder(model, config.semantic_encoder, device)

    def save() -> None:
        save_torch(
            {"model": state_tensors(model), "optimizer": optimizer.state_dict(), "step": step, "rows": rows,
             "trained_s": trained_s},
            state_path,
        )  # fmt: skip
        write_json(os.path.join(config.out_dir, "metrics.json"), rows)

    resumed_at = step
    bar = tqdm(total=config.steps, initial=step, desc="pretraining", unit="step", disable=not progress)
    mark = time.perf_counter()
    try:
        while step < config.steps:
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(config, step)
            batch = crops.step_batch(config.seed, step, config.batch_size)
            scenes = None
            if maps is not None:
                scenes = step_scene_batch(maps, config.seed, step, config.dense_scenes, config.dense_scale)
            logged = train_step(model, text, batch, optimizer, device, scenes, config.dense_weight)
            step += 1
            bar.update(1)
            if step % config.log_every == 0 or step == config.steps:
                trained_s += time.perf_counter() - mark
                mark = time.perf_counter()
                rounded = {k: round(v, 5) for k, v in logged.items()}
                rows.append({"step": step, **rounded, "seconds": round(trained_s, 1)})
                bar.set_postfix(loss=f"{logged['loss']:.3f}", acc=f"{logged['accuracy']:.2f}")
            if step % config.save_every == 0 or step == config.steps:
                save()
    finally:
        bar.close()
    weights = save_open_clip(model, config.semantic_encoder, config.out_dir, step, config.to_dict())
    record: dict[str, Any] = {
        "config": config.to_dict(),
        "semantic_encoder": config.semantic_encoder,
        "weights": weights,
        "steps": step,
        "resumed_at": resumed_at or None,
        "crops": {"train": len(crops), **rendered},
        "seconds": {"render": round(render_s, 1), "train": round(trained_s, 1)},
        "final": rows[-1] if rows else None,
    }
    if probe:
        probe_crops = load_crops(config.cache_dir, "probe", config.probe_scenes)
        probe_maps = load_scene_maps(config.cache_dir, "probe", config.probe_scenes)
        mark = time.perf_counter()
        record["probe"] = {
            which: probe_weights(source, config.semantic_encoder, probe_crops, device, probe_maps, config.dense_scale)
            for which, source in (("random", "random"), ("pretrained", weights))
        }
        record["seconds"]["probe"] = round(time.perf_counter() - mark, 1)
    record["seconds"]["total"] = round(time.perf_counter() - start, 1)
    record["environment"] = measurement_environment()
    write_json(os.path.join(config.out_dir, RECORD_FILE), record)
    return record


def summary_lines(record: dict[str, Any]) -> list[str]:
    """A few readable lines of a run's record: weights, time, and the probe's colour and shape scores."""
    lines = [f"weights: {record['weights']} ({record['semantic_encoder']}, {record['steps']} steps)"]
    seconds = record["seconds"]
    lines.append(", ".join(f"{k} {v:.0f} s" for k, v in seconds.items()))
    for which, result in record.get("probe", {}).items():
        parts = []
        for key in ("colors", "shapes"):
            r = result[key]
            parts.append(f"{key} seen {_pct(r['seen'])}, unseen {_pct(r['unseen'])} (chance {100 * r['chance']:.0f} %)")
        if "dense" in result:
            for noun in ("blocks", "bowls"):
                r = result["dense"][noun]
                parts.append(f"{noun}' pixels seen {_share(r['seen'])}, unseen {_share(r['unseen'])}")
        lines.append(f"probe, {which} weights: " + "; ".join(parts))
    return lines


def _share(score: dict[str, Any]) -> str:
    return "n/a" if score["share"] is None else f"{100 * score['share']:.0f} %"


def _pct(score: dict[str, Any]) -> str:
    return "n/a" if score["top1"] is None else f"{100 * score['top1']:.0f} % of {score['n']}"


__all__ = ["learning_rate", "make_optimizer", "pretrain", "summary_lines", "train_step"]
