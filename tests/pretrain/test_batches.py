"""Batches: a caption per crop, true of it; a batch is a function of the seed and the step."""

from __future__ import annotations

import numpy as np
import torch

from cliport.pretrain.batches import CaptionedCrops, caption_for, facts_of, resize_images
from cliport.pretrain.cache import load_crops


def test_every_caption_is_true_of_its_crop_and_marked(tiny_cache: str, train_scenes: int) -> None:
    crops = CaptionedCrops(load_crops(tiny_cache, "train", train_scenes), 32)
    batch = crops.step_batch(seed=0, step=3, batch_size=16)
    assert batch.images.shape == (16, 3, 32, 32) and 0 <= batch.images.min() and batch.images.max() <= 1
    assert bool(batch.positives.diagonal().all())
    again = crops.step_batch(seed=0, step=3, batch_size=16)
    assert again.captions == batch.captions and torch.equal(again.images, batch.images)
    assert crops.step_batch(seed=0, step=4, batch_size=16).captions != batch.captions
    rng = np.random.default_rng(0)
    for meta in crops.meta:
        _, key = caption_for(meta, rng)
        assert key in facts_of(meta)


def test_resize_averages_areas() -> None:
    images = np.zeros((1, 4, 4, 3), np.uint8)
    images[0, :2, :2] = 200
    out = resize_images(images, 2)
    assert out.shape == (1, 3, 2, 2) and out.dtype == torch.uint8
    assert out[0, :, 0, 0].tolist() == [200, 200, 200] and out[0, :, 1, 1].tolist() == [0, 0, 0]
