"""The 20 kit shapes: convex pieces, size, symmetry periods, split, and that each builds a sound body."""

import math

import cv2
import numpy as np
import pybullet as p
import pytest

from cliport.env import shapes
from cliport.tasks.kit_shapes import HEIGHT, SHAPES, TEST_SHAPES, TRAIN_SHAPES, build_shape, split_shapes

NAMES = "R A triangle square plus T diamond pentagon rectangle flower star circle G V E L ring hexagon heart M".split()
RES = 0.00025  # raster cell (m)
GRID = 400


def raster(index: int, angle: float) -> np.ndarray:
    """The shape's outline rotated by ``angle`` about its origin, as a boolean mask."""
    c, s = math.cos(angle), math.sin(angle)
    img = np.zeros((GRID, GRID), np.uint8)
    for piece in SHAPES[index].pieces:
        pts = piece @ np.array([[c, -s], [s, c]]).T
        cv2.fillPoly(img, [np.round((pts / RES + GRID / 2) * 16).astype(np.int32)], 1, shift=4)
    return img.astype(bool)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_order_labels_and_split():
    assert [s.name for s in SHAPES] == NAMES
    assert SHAPES[0].label == "letter R" and SHAPES[19].label == "letter M" and SHAPES[16].label == "ring"
    assert TRAIN_SHAPES == list(range(14)) and TEST_SHAPES == list(range(14, 20))
    assert split_shapes("train") == TRAIN_SHAPES
    assert split_shapes("val") == split_shapes("test") == TEST_SHAPES


def test_symmetry_periods():
    periods = {s.name: s.symmetry for s in SHAPES}
    assert periods["square"] == periods["plus"] == periods["flower"] == math.pi / 2
    assert periods["circle"] == periods["ring"] == 0.0
    assert periods["triangle"] == pytest.approx(2 * math.pi / 3)
    assert periods["star"] == periods["pentagon"] == pytest.approx(2 * math.pi / 5)
    assert periods["hexagon"] == pytest.approx(math.pi / 3)
    assert periods["rectangle"] == periods["diamond"] == math.pi
    for name in "R A T G V E L M heart".split():
        assert periods[name] == 2 * math.pi


@pytest.mark.parametrize("index", range(20))
def test_pieces_are_convex_and_shape_is_about_6cm(index):
    for piece in SHAPES[index].pieces:
        edges = np.roll(piece, -1, axis=0) - piece
        cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
        assert np.all(cross > -1e-12), "pieces must be convex and counter-clockwise"
    pts = np.concatenate(SHAPES[index].pieces)
    assert 0.045 <= (pts.max(axis=0) - pts.min(axis=0)).max() <= 0.07


@pytest.mark.parametrize("index", range(20))
def test_rotation_by_period_maps_outline_onto_itself(index):
    shape = SHAPES[index]
    base = raster(index, 0.0)
    if shape.symmetry == 0:
        for angle in (0.3, 1.1, 2.5):
            assert iou(base, raster(index, angle)) > 0.97
        return
    assert iou(base, raster(index, shape.symmetry)) > 0.97
    for k in (2, 3, 4, 5, 6):  # the period is the smallest one
        assert iou(base, raster(index, shape.symmetry / k)) < 0.93


def test_every_shape_builds_a_resting_body_of_the_right_size(tmp_path):
    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.8, physicsClientId=client)
        p.setTimeStep(1 / 480, physicsClientId=client)
        shapes.box(client, (2, 2, 0.1), ((0, 0, -0.05), (0, 0, 0, 1)), mass=0.0)
        bodies = []
        for index in range(20):
            pose = ((0.12 * (index % 5), 0.12 * (index // 5), HEIGHT / 2 + 0.002), (0, 0, 0, 1))
            bodies.append(build_shape(client, str(tmp_path), index, pose, (255, 0, 0)))
        for _ in range(480):
            p.stepSimulation(physicsClientId=client)
        for index, body in enumerate(bodies):
            lo, hi = (np.asarray(v) for v in p.getAABB(body, physicsClientId=client))
            pts = np.concatenate(SHAPES[index].pieces)
            # PyBullet pads convex meshes' AABBs by their collision margin (a few mm).
            np.testing.assert_allclose((hi - lo)[:2], pts.max(axis=0) - pts.min(axis=0), atol=0.01)
            assert hi[2] - lo[2] == pytest.approx(HEIGHT, abs=0.01)
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=client)
            assert pos[2] == pytest.approx(HEIGHT / 2, abs=0.002), SHAPES[index].name
            assert abs(quat[0]) < 0.01 and abs(quat[1]) < 0.01, f"{SHAPES[index].name} tipped over"
            np.testing.assert_allclose(SHAPES[index].half_extents, [*np.abs(pts).max(axis=0), HEIGHT / 2])
    finally:
        p.disconnect(client)
