"""Rendering: the same seed gives the same crops, and a crop shows what its metadata says."""

from __future__ import annotations

import numpy as np
import pytest

from cliport.env.heightmap import BOUNDS, PIXEL_SIZE, heightmap_shape
from cliport.pretrain.render import TABLE_LABEL, SceneRenderer
from cliport.pretrain.scenes import make_scene
from cliport.pretrain.vocabulary import relation_of
from cliport.tasks.colors import COLORS


@pytest.fixture(scope="module")
def renderer() -> SceneRenderer:
    with SceneRenderer(camera_scale=0.5, crop_px=64, renderer="cpu") as scene_renderer:
        yield scene_renderer


def test_rendering_is_deterministic_per_seed(renderer: SceneRenderer) -> None:
    (first, first_map), (other, _), (again, again_map) = renderer.render(3), renderer.render(4), renderer.render(3)
    assert [c.meta() for c in first] == [c.meta() for c in again]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(first, again, strict=True))
    assert not np.array_equal(first[0].image, other[0].image)
    assert np.array_equal(first_map.color, again_map.color) and np.array_equal(first_map.labels, again_map.labels)


def test_crops_show_their_subject(renderer: SceneRenderer) -> None:
    """Each object gets a top-down and an oblique crop naming it first; a block's top-down crop is its colour in
    the middle; a relation crop's relation holds between its two objects' positions."""
    checked = 0
    for seed in range(4):
        objects, (crops, _) = make_scene(seed), renderer.render(seed)
        assert len(crops) >= 2 * len(objects)
        for i, obj in enumerate(objects):
            top, oblique = crops[2 * i], crops[2 * i + 1]
            assert (top.view, oblique.view) == ("top", "oblique")
            assert top.things[0] == oblique.things[0] == obj.thing.to_list()
            assert top.image.shape == oblique.image.shape == (64, 64, 3) and top.image.dtype == np.uint8
            if obj.thing.kind == "block":  # the block's own pixels (rows along y, columns along x; 3 x 3 around it)
                x, y, side = top.window
                row, col = (int(64 * ((c - m) / side + 0.5)) for c, m in ((obj.xyz[1], y), (obj.xyz[0], x)))
                pixels = top.image[row - 1 : row + 2, col - 1 : col + 2].reshape(-1, 3).astype(float)
                pixels = pixels[pixels.sum(1) > 0]  # cells no camera saw are black in every observation
                distance = np.linalg.norm(np.median(pixels, 0) - np.asarray(COLORS[obj.thing.color], float))
                assert distance < 60, (obj.thing, np.median(pixels, 0))
                checked += 1
        for crop in crops[2 * len(objects) :]:
            i, relation, j = crop.relation
            assert crop.positions is not None and relation_of(crop.positions[i], crop.positions[j]) == relation
    assert checked >= 2


def test_a_scene_map_labels_each_object_where_it_lies(renderer: SceneRenderer) -> None:
    """The map's labels name each object at its centre (rows along y, columns along x), the rest is table, and a
    block's labelled pixels are its colour; a 4 cm block covers about 13 x 13 cells of 3.125 mm."""
    for seed in range(3):
        objects, (_, scene_map) = make_scene(seed), renderer.render(seed)
        assert scene_map.things == [o.thing.to_list() for o in objects]
        assert scene_map.color.shape[:2] == scene_map.labels.shape == heightmap_shape()
        for k, obj in enumerate(objects):
            mask = scene_map.labels == k + 1
            row = int((obj.xyz[1] - BOUNDS[1, 0]) / PIXEL_SIZE)
            col = int((obj.xyz[0] - BOUNDS[0, 0]) / PIXEL_SIZE)
            if obj.thing.kind == "block":
                assert scene_map.labels[row, col] == k + 1
                assert 100 <= mask.sum() <= 260, mask.sum()
                median = np.median(scene_map.color[mask].astype(float), 0)
                assert np.linalg.norm(median - np.asarray(COLORS[obj.thing.color], float)) < 60
        assert (scene_map.labels == TABLE_LABEL).mean() > 0.5
