"""The dense objective: segment-balanced pixel loss, windows on the trunk's cells, a tiny model that learns it, and
the dense probe's counts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cliport.models.encoders.clip_weights import create_clip_model
from cliport.pretrain.batches import CaptionedCrops
from cliport.pretrain.cache import SceneMaps, load_crops, load_scene_maps
from cliport.pretrain.dense import (
    TABLE_CAPTION,
    WINDOW_PX,
    _window,
    dense_loss,
    dense_probe,
    pixel_logits,
    scene_batch,
    step_scene_batch,
)
from cliport.pretrain.probe import normalise
from cliport.pretrain.render import TABLE_LABEL, UNKNOWN_LABEL
from cliport.pretrain.trainer import TextEncoder, make_optimizer, train_step


def test_dense_loss_weighs_each_segment_the_same_and_leaves_out_unlabelled_pixels() -> None:
    """Two segments, one of 1 pixel and one of 3, one left out: the loss is the mean of the two segments' mean
    cross-entropies, the second's target split over its two true captions."""
    logits = torch.tensor([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0], [9.0, -9.0, 0.0]])
    logits = logits.T.reshape(1, 3, 1, 5)  # five pixels in a row
    labels = torch.tensor([[[0, 1, 1, 1, -1]]])
    positives = torch.tensor([[True, False, False], [False, True, True]])
    log_p = torch.log_softmax(logits[0, :, 0].T, dim=1)
    first = -log_p[0, 0]
    second = -(0.5 * (log_p[1:4, 1] + log_p[1:4, 2])).mean()
    assert float(dense_loss(logits, labels, positives)) == pytest.approx(float((first + second) / 2), rel=1e-6)


def _synthetic_maps() -> SceneMaps:
    """Two 160 x 144 scenes: a red block and a blue bowl on grey, a robot's cells at a corner."""
    color = np.full((2, 160, 144, 3), 60, np.uint8)
    labels = np.full((2, 160, 144), TABLE_LABEL, np.uint8)
    labels[:, :5, :5] = UNKNOWN_LABEL
    for i in range(2):
        labels[i, 30 + 40 * i : 43 + 40 * i, 20:33] = 1
        color[i][labels[i] == 1] = (230, 40, 40)
        labels[i, 100:140, 50:90] = 2
        color[i][labels[i] == 2] = (40, 40, 230)
    things = [[["block", "block", "red"], ["bowl", "bowl", "blue"]]] * 2
    return SceneMaps(color, labels, things)


def test_windows_lie_on_the_cells_and_caption_what_they_show() -> None:
    maps = _synthetic_maps()
    rng = np.random.default_rng(0)
    for _ in range(20):
        row, col = _window(maps.labels[0], rng)
        assert row % 16 == 0 and col % 16 == 0 and 0 <= row <= 160 - WINDOW_PX and 0 <= col <= 144 - WINDOW_PX
    batch = scene_batch(maps, np.array([0, 1]), np.random.default_rng(1), scale=2.0)
    assert batch.images.shape == (2, 3, 2 * WINDOW_PX, 2 * WINDOW_PX) and batch.labels.shape == (2,) + (WINDOW_PX,) * 2
    assert batch.captions[0] == TABLE_CAPTION
    for s in range(len(batch.positives)):
        true_of = [batch.captions[k] for k in np.flatnonzero(batch.positives[s].numpy())]
        assert true_of and all(("table" in t) == (true_of[0] == TABLE_CAPTION) for t in true_of), true_of
    assert set(batch.labels.unique().tolist()) - {-1} == set(range(len(batch.positives)))
    images = batch.images.permute(0, 2, 3, 1)[:, ::2, ::2]  # back at the map's pixels
    for s in range(len(batch.positives)):  # each object's pixels are its own colour: the red block, the blue bowl
        true_of = " ".join(batch.captions[k] for k in np.flatnonzero(batch.positives[s].numpy()))
        if "table" not in true_of:
            channel = 0 if "block" in true_of else 2
            assert float(images[batch.labels == s][:, channel].median()) > 0.8, true_of


def test_the_dense_objective_learns_a_tiny_set(tiny_cache: str, train_scenes: int, tiny_config) -> None:
    """15 steps of cliport-RN-tiny with the dense objective on 6 rendered scenes: on a fixed batch of their windows
    the dense loss falls by a quarter (measured: 2.58 -> 1.73)."""
    config = tiny_config("unused", tiny_cache)
    maps = load_scene_maps(tiny_cache, "train", train_scenes)
    crops = CaptionedCrops(load_crops(tiny_cache, "train", train_scenes), 32)
    model = create_clip_model(config.semantic_encoder, config.seed).train()
    optimizer = make_optimizer(model, config)
    text = TextEncoder(model, config.semantic_encoder, "cpu")
    fixed = step_scene_batch(maps, seed=99, step=0, scenes=4, scale=2.0)

    def loss() -> float:
        with torch.no_grad():
            images = normalise(model, fixed.images)
            logits = pixel_logits(model.visual, images, text(fixed.captions), model.logit_scale, (WINDOW_PX,) * 2)
            return float(dense_loss(logits, fixed.labels, fixed.positives))

    before = loss()
    for step in range(15):
        batch = crops.step_batch(config.seed, step, 8)
        train_step(model, text, batch, optimizer, "cpu", step_scene_batch(maps, config.seed, step, 4, 2.0), 1.0)
    after = loss()
    assert math.isfinite(after) and after < 0.75 * before, (before, after)


def test_the_dense_probe_counts_each_block_and_bowl_pixel() -> None:
    maps = _synthetic_maps()
    model = create_clip_model("cliport-RN-tiny", 0)
    result = dense_probe(model, "cliport-RN-tiny", maps, scale=2.0)
    assert result["blocks"]["seen"]["objects"] == 2 and result["blocks"]["seen"]["pixels"] == 2 * 13 * 13
    assert result["bowls"]["seen"]["pixels"] == 2 * 40 * 40 and result["blocks"]["unseen"]["share"] is None
    assert 0 <= result["blocks"]["seen"]["share"] <= 1
