"""The dense objective: each pixel of a scene's top-down map scored against the captions of the scene's things.

The contrastive loss (:mod:`cliport.pretrain.loss`) aligns one pooled embedding per crop with text. An agent's
similarity maps read something else: the encoder's text-aligned embedding at every position of its last trunk
level (:func:`~cliport.models.encoders.dense_clip.dense_embeddings`), on the whole map, resized bilinearly to the
map's pixels. This objective trains that path directly, with the simulator's object masks
(:class:`~cliport.pretrain.render.SceneMap`):

- a batch is ``scenes`` windows of whole scenes' maps, each :data:`WINDOW_PX` map pixels square around a random
  object and aligned to the trunk's cells, read at ``scale`` times their size (the scale agents read maps at);
- its captions: one per object (a random template, the colour sometimes left out, as the crops'), and
  :data:`TABLE_CAPTION` for the table;
- each pixel's logits are its position's embedding against every caption at CLIP's temperature (the cell's
  logits resized bilinearly to the pixels), and its target is spread over the captions true of what it shows;
- each segment (an object, or a window's table) weighs the same, so that the table's many pixels do not swamp
  the 4 cm blocks. Pixels the masks leave out (the robot, nothing seen) do not count.

:func:`dense_probe` measures what this trains on held-out scenes: the share of a block's or bowl's pixels whose
best caption of the eleven colours names its own, seen and unseen colours apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from cliport.models.encoders.base import TRUNK_STRIDES
from cliport.models.encoders.clip_encoder import trunk_levels
from cliport.models.encoders.dense_clip import dense_embeddings
from cliport.pretrain.cache import SceneMaps
from cliport.pretrain.render import TABLE_LABEL, UNKNOWN_LABEL
from cliport.pretrain.vocabulary import (
    COLOR_NAMES,
    UNSEEN_COLORS,
    Thing,
    crop_facts,
    probe_color_caption,
    thing_caption,
)

#: The caption of the table's pixels.
TABLE_CAPTION, TABLE_KEY = "the table", "table"
#: Side (map pixels) of a window of a scene's map; a multiple of half the trunk's stride, so that at scale 2 its
#: cells are the cells of the whole map the agents read.
WINDOW_PX = 128
_CELL = TRUNK_STRIDES[-1] // 2


@dataclass
class SceneBatch:
    """``images`` (B, 3, S, S) float in [0, 1] (windows at the read scale); ``labels`` (B, P, P) long, each window
    pixel's segment (-1: not counted); ``captions`` (K,); ``positives`` (segments, K) bool: caption k true of
    segment s."""

    images: torch.Tensor
    labels: torch.Tensor
    captions: list[str]
    positives: torch.Tensor


def _window(labels: np.ndarray, rng: np.random.Generator) -> tuple[int, int]:
    """The top-left (row, col) of a :data:`WINDOW_PX` window around a random object of a scene, on the cell grid."""
    rows, cols = labels.shape
    objects = np.argwhere((labels != TABLE_LABEL) & (labels != UNKNOWN_LABEL))
    if len(objects):
        centre = objects[int(rng.integers(len(objects)))] + rng.integers(-WINDOW_PX // 4, WINDOW_PX // 4 + 1, 2)
    else:
        centre = np.array([rows // 2, cols // 2])
    top = [
        int(np.clip(round((c - WINDOW_PX / 2) / _CELL) * _CELL, 0, max(0, side - WINDOW_PX)))
        for c, side in zip(centre, (rows, cols), strict=True)
    ]
    return top[0], top[1]


def scene_batch(maps: SceneMaps, indices: np.ndarray, rng: np.random.Generator, scale: float) -> SceneBatch:
    """Windows of the scenes ``indices`` (one each) with their captions and segments (module docstring)."""
    captions: dict[str, str] = {TABLE_CAPTION: TABLE_KEY}  # text -> key
    segment_facts: list[set[str]] = []
    images, labels = [], []
    for index in indices:
        scene_labels = maps.labels[int(index)]
        row, col = _window(scene_labels, rng)
        window = (slice(row, row + WINDOW_PX), slice(col, col + WINDOW_PX))
        raw = scene_labels[window]
        segment = np.full(raw.shape, -1, np.int64)
        segment[raw == TABLE_LABEL] = len(segment_facts)
        segment_facts.append({TABLE_KEY})
        for k in np.unique(raw):
            if k in (TABLE_LABEL, UNKNOWN_LABEL):
                continue
            thing = Thing.from_list(maps.things[int(index)][int(k) - 1])
            text, key = thing_caption(thing, rng)
            captions.setdefault(text, key)
            segment[raw == k] = len(segment_facts)
            segment_facts.append(crop_facts([thing]))
        labels.append(torch.from_numpy(segment))
        images.append(torch.from_numpy(np.ascontiguousarray(maps.color[int(index)][window])))
    texts = list(captions)
    positives = torch.tensor([[captions[t] in facts for t in texts] for facts in segment_facts], dtype=torch.bool)
    rgb = torch.stack(images).permute(0, 3, 1, 2).float() / 255
    if scale != 1.0:
        size = [round(side * scale) for side in rgb.shape[-2:]]
        rgb = F.interpolate(rgb, size=size, mode="bilinear", align_corners=False, antialias=scale < 1)
    return SceneBatch(rgb, torch.stack(labels), texts, positives)


def step_scene_batch(maps: SceneMaps, seed: int, step: int, scenes: int, scale: float) -> SceneBatch:
    """Step ``step``'s scene batch of a run seeded ``seed``: ``scenes`` distinct scenes, a window each."""
    rng = np.random.default_rng([seed, step, 2])  # apart from the crops' batch of the same step
    indices = rng.choice(len(maps), size=min(scenes, len(maps)), replace=False)
    return scene_batch(maps, indices, rng, scale)


def pixel_logits(
    visual: Any, images: torch.Tensor, texts: torch.Tensor, logit_scale: torch.Tensor, size: tuple[int, int]
) -> torch.Tensor:
    """Normalised images (N, 3, H, W) and L2-normalised texts (K, E) -> each position's scaled cosine with each
    text, resized bilinearly to ``size`` (N, K, *size)."""
    dense = F.normalize(dense_embeddings(visual, trunk_levels(visual, images)[-1]), dim=1)
    logits = logit_scale.exp() * torch.einsum("nehw,ke->nkhw", dense, texts)
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=False)


def dense_loss(logits: torch.Tensor, labels: torch.Tensor, positives: torch.Tensor) -> torch.Tensor:
    """Pixel logits (N, K, H, W), each pixel's segment (N, H, W) long (-1: left out) and which captions are true
    of each segment (S, K) bool -> the segment-balanced cross-entropy (a scalar): each pixel's target spread
    evenly over its segment's true captions, each segment's pixels averaged, the segments averaged."""
    valid = labels >= 0
    segments = labels[valid]  # (P,)
    log_p = F.log_softmax(logits, dim=1).permute(0, 2, 3, 1)[valid]  # (P, K)
    targets = positives.float() / positives.sum(1, keepdim=True).clamp(min=1)
    per_pixel = -(targets[segments] * log_p).sum(1)
    counts = torch.bincount(segments, minlength=len(positives)).float()
    return (per_pixel / counts[segments]).sum() / (counts > 0).sum().clamp(min=1)


@torch.no_grad()
def dense_probe(
    model: Any, model_name: str, maps: SceneMaps, scale: float, device: str = "cpu", chunk: int = 8
) -> dict[str, Any]:
    """On whole held-out scenes read at ``scale``: for blocks and bowls, the share of an object's pixels whose
    best of the eleven "a {colour} {noun}" captions names its colour, pooled over pixels, seen and unseen
    colours apart. Returns ``{"blocks": {"seen": {"share", "pixels", "objects"}, "unseen": ...}, "bowls": ...}``."""
    from cliport.pretrain.probe import embed_texts, normalise

    nouns = ("block", "bowl")
    rows, cols = maps.labels.shape[1:]
    size = [max(_CELL * 2, round(side * scale / (2 * _CELL)) * 2 * _CELL) for side in (rows, cols)]
    tally = {(noun, part): [0, 0, 0] for noun in nouns for part in ("seen", "unseen")}  # right, pixels, objects
    was_training = model.training
    model.eval()
    try:
        captions = [probe_color_caption(color, noun) for noun in nouns for color in COLOR_NAMES]
        texts = embed_texts(model, model_name, captions, device)  # (nouns * colours, E)
        for start in range(0, len(maps), chunk):
            rgb = torch.from_numpy(maps.color[start : start + chunk]).permute(0, 3, 1, 2).float().to(device) / 255
            rgb = normalise(model, F.interpolate(rgb, size=size, mode="bilinear", align_corners=False))
            logits = pixel_logits(model.visual, rgb, texts.to(device), torch.zeros(()), (rows, cols)).cpu()
            best = logits.unflatten(1, (len(nouns), len(COLOR_NAMES))).argmax(2)  # (N, nouns, H, W)
            for i, things in enumerate(maps.things[start : start + chunk]):
                labels = torch.from_numpy(maps.labels[start + i])
                for k, (kind, _, color) in enumerate(things):
                    mask = labels == k + 1
                    if kind not in nouns or not mask.any():
                        continue
                    counts = tally[(kind, "unseen" if color in UNSEEN_COLORS else "seen")]
                    counts[0] += int((best[i, nouns.index(kind)][mask] == COLOR_NAMES.index(color)).sum())
                    counts[1] += int(mask.sum())
                    counts[2] += 1
    finally:
        model.train(was_training)
    return {f"{noun}s": {part: _share(*tally[(noun, part)]) for part in ("seen", "unseen")} for noun in nouns}


def _share(right: int, pixels: int, objects: int) -> dict[str, Any]:
    return {"share": round(right / pixels, 4) if pixels else None, "pixels": pixels, "objects": objects}
