"""Dense retrieval: a caption is found when the block it names scores highest under its similarity map."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cliport.models.encoders.clip_encoder import load_clip
from cliport.pretrain.dense_retrieval import block_scores, caption_maps, dense_retrieval, found


def _masks() -> dict[str, np.ndarray]:
    masks = {name: np.zeros((8, 6), dtype=bool) for name in ("red", "pink", "blue")}
    masks["red"][0:2, 0:2] = masks["pink"][4:6, 0:2] = masks["blue"][4:6, 4:6] = True
    return masks


def test_a_map_bright_on_the_named_block_finds_it_and_a_swapped_one_does_not() -> None:
    masks = _masks()
    maps = torch.stack([torch.from_numpy(mask).float() for mask in masks.values()])  # caption c bright on block c
    assert found(block_scores(maps, masks)) == {"red": True, "pink": True, "blue": True}
    swapped = maps[[1, 0, 2]]  # "red" bright on pink and "pink" on red
    assert found(block_scores(swapped, masks)) == {"red": False, "pink": False, "blue": True}


def test_caption_maps_cover_the_map_at_any_scale() -> None:
    encoder = load_clip("random", "cliport-RN-tiny")
    color = np.random.default_rng(0).integers(0, 256, (96, 64, 3), dtype=np.uint8)
    for scale in (0.5, 1.0):  # 48 x 32 is padded to 64 x 32 for the trunk, and cut back
        maps = caption_maps(encoder, color, ["a red block", "a pink block"], scale)
        assert maps.shape == (2, 96, 64) and maps.abs().max() <= 1.0 + 1e-5
        assert not torch.allclose(maps[0], maps[1])


def test_caption_maps_against_a_bank_are_probabilities() -> None:
    encoder = load_clip("random", "cliport-RN-tiny")
    color = np.random.default_rng(0).integers(0, 256, (96, 64, 3), dtype=np.uint8)
    maps = caption_maps(encoder, color, ["a red block", "a pink block"], 1.0, bank=["a red block", "a blue bowl"])
    assert maps.shape == (2, 96, 64) and maps.min() >= 0 and maps.max() <= 1
    # "a red block" competes with "a blue bowl" alone (itself left out), "a pink block" with both: a random
    # encoder's texts are nearly alike, so about 1/2 against 1/3 everywhere
    assert (maps[0] > maps[1]).all()


def test_dense_retrieval_counts_every_block_of_each_scene_once() -> None:
    encoder = load_clip("random", "cliport-RN-tiny")
    report = dense_retrieval(encoder, "put-one-block-in-bowl-unseen-colors", [10001], scale=0.5, camera_scale=0.5)
    assert report["scenes"] == 1 and report["seen"]["n"] + report["unseen"]["n"] == 3 == len(report["records"])
    assert {r["color"] for r in report["records"]} <= set(
        ["blue", "red", "green", "orange", "purple", "pink", "white"]
    )  # fmt: skip


def test_dense_retrieval_needs_a_lesson_task() -> None:
    from cliport.errors import ConfigError

    with pytest.raises(ConfigError, match="names its blocks' colours"):
        dense_retrieval(load_clip("random", "cliport-RN-tiny"), "block-insertion", [0])
