"""The crop cache: rendered once, resumed shard by shard, refused when rendered with other settings."""

from __future__ import annotations

import os

import numpy as np
import pytest

from cliport.errors import ConfigError
from cliport.pretrain import cache
from cliport.pretrain.cache import PROBE_FIRST_SEED, load_crops, load_scene_maps, render_cache


def test_render_once_then_only_what_is_missing(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(cache, "SCENES_PER_SHARD", 1)
    folder = str(tmp_path / "crops")
    first = render_cache(folder, {"train": 2}, renderer="cpu", progress=False)
    assert first["rendered_scenes"] == 2 and first["shards"] == 2
    shard = os.path.join(folder, "train", "seeds-000000-000000.npz")
    stamp = os.stat(shard).st_mtime_ns
    again = render_cache(folder, {"train": 3, "probe": 1}, renderer="cpu", progress=False)
    assert again["rendered_scenes"] == 2  # train scene 2 and one probe scene
    assert os.stat(shard).st_mtime_ns == stamp
    train, probe = load_crops(folder, "train", 3), load_crops(folder, "probe", 1)
    assert [m["seed"] for m in train.meta] == sorted(m["seed"] for m in train.meta)
    assert {m["seed"] for m in train.meta} == {0, 1, 2} and {m["seed"] for m in probe.meta} == {PROBE_FIRST_SEED}
    assert train.images.shape == (len(train), 64, 64, 3) and train.images.dtype == np.uint8
    maps = load_scene_maps(folder, "train", 3)
    assert maps.color.shape == (3, 320, 160, 3) and maps.labels.shape == (3, 320, 160) and len(maps) == 3
    for labels, things in zip(maps.labels, maps.things, strict=True):  # objects never overlap: each is seen
        assert set(np.unique(labels)) - {255} == set(range(len(things) + 1))
    assert not [p for p in os.listdir(os.path.join(folder, "train")) if p.endswith(".tmp")]


def test_other_settings_and_missing_crops_are_one_line_errors(tmp_path) -> None:
    folder = str(tmp_path / "crops")
    render_cache(folder, {"probe": 1}, renderer="cpu", progress=False)
    with pytest.raises(ConfigError, match="other settings.*crop_px"):
        render_cache(folder, {"probe": 1}, crop_px=32, renderer="cpu", progress=False)
    with pytest.raises(ConfigError, match="lacks the crops of train scenes"):
        load_crops(folder, "train", 1)
