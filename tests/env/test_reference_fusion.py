"""Observation parity with the reference CLIPort: the same camera images give the same fused maps, and
pixels, poses and rotations convert alike.

The reference's functions (``cliport/utils/utils.py``, ``cliport/tasks/cameras.py``) run in a
subprocess (tests/support/run_reference_utils.py) from the folder that ``--reference-dir`` or
``$CLIPORT_REFERENCE_DIR`` names; without one these tests are skipped.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from cliport import tasks
from cliport.env import cameras as cams
from cliport.env import heightmap as hm
from cliport.env import transforms as tf
from cliport.env.environment import EnvConfig, Environment


def _configs_json(configs: list[cams.CameraConfig]) -> np.ndarray:
    """Our cameras in the reference's config format (its functions read intrinsics, position, rotation)."""
    return np.array(json.dumps([dataclasses.asdict(c) for c in configs]))


def _simulated_views(task: str, seed: int, scale: float, actions: int = 0) -> tuple[list, list[cams.CameraConfig]]:
    """Our simulator's raw camera images of a task's scene (after ``actions`` oracle actions)."""
    env = Environment(EnvConfig.defaults(camera_scale=scale, raw_images=True), task=tasks.make(task, "train"))
    with env:
        obs = env.reset(seed)
        for _ in range(actions):
            obs, _, _, _ = env.step(env.task.oracle_act(obs))
        views = [(c["color"], c["depth"]) for c in obs["cameras"]]
        # The observation the agents get is this very fusion of these images.
        fused = hm.fuse_cameras(views, env.camera_configs, env.bounds, env.pixel_size)
        np.testing.assert_array_equal(obs["color"], fused.color)
        np.testing.assert_array_equal(obs["height"], fused.height)
        return views, list(env.camera_configs)


def _compare_fusion(
    reference_utils, folder, views: list, configs: list[cams.CameraConfig], bounds: np.ndarray = hm.BOUNDS
) -> dict[str, float]:
    """Fuse ``views`` with ours and the reference's rule; assert equal maps; return the measured errors."""
    ref = reference_utils(
        folder,
        "fuse",
        color=np.stack([c for c, _ in views]),
        depth=np.stack([d for _, d in views]),
        configs=_configs_json(configs),
        bounds=bounds,
        pixel_size=np.array(hm.PIXEL_SIZE),
    )
    for i, ((color, depth), cam) in enumerate(zip(views, configs, strict=True)):
        points = hm.transform_points(
            hm.pointcloud_from_depth(depth, cam.K), tf.quat_to_matrix(cam.rotation), cam.position
        )
        np.testing.assert_array_equal(points, ref["points"][i], err_msg=f"camera {i} world points")
        height, color_map, seen = hm.project_to_heightmap(points, color, bounds)
        np.testing.assert_array_equal(color_map, ref["colormaps"][i], err_msg=f"camera {i} colour map")
        assert np.abs(height - ref["heightmaps"][i]).max() <= 1e-6, f"camera {i} height map"
        assert seen.sum() > 500, f"camera {i} sees too little of the workspace for a meaningful test"
    fused = hm.fuse_cameras(views, configs, bounds)
    np.testing.assert_array_equal(fused.color, ref["cmap"])
    height_error = float(np.abs(fused.height - ref["hmap"]).max())
    assert height_error <= 1e-6
    # The agents' input: colour then the height three times, as the reference's get_image stacks them.
    from cliport.models.preprocess import raw_input

    x = raw_input(fused.color, fused.height)[0].permute(1, 2, 0)
    stacked = np.concatenate([ref["cmap"], *[ref["hmap"][..., None]] * 3], axis=2)
    np.testing.assert_allclose((x * torch.tensor([255.0] * 3 + [1.0] * 3)).numpy(), stacked, rtol=0, atol=1e-4)
    return {"height_max_abs_error": height_error, "colour_cells_differing": int((fused.color != ref["cmap"]).sum())}


@pytest.mark.parametrize(
    ("task", "seed", "scale", "actions"),
    [
        ("put-block-in-bowl-seen-colors", 0, 0.5, 0),
        ("put-block-in-bowl-seen-colors", 2, 0.5, 1),  # a block lifted into a bowl: stacked heights
        ("stack-block-pyramid", 0, 1.0, 0),  # full resolution, the reference's own
    ],
)
def test_fused_maps_equal_the_reference(reference_utils, tmp_path, task, seed, scale, actions):
    views, configs = _simulated_views(task, seed, scale, actions)
    errors = _compare_fusion(reference_utils, tmp_path, views, configs)
    assert errors == {"height_max_abs_error": 0.0, "colour_cells_differing": 0}


def test_fusion_rule_on_ties_black_and_edges(reference_utils, tmp_path):
    """Synthetic views that the rule's details decide: flat planes (many points of equal z in one cell,
    so the sort's order of ties picks the colour), black points, points on the lower z bound, no
    readings; two cameras looking down, one tilted; with the simulator's bounds and with moved ones."""
    rng = np.random.default_rng(0)
    rows, cols = 90, 120
    # Focal lengths for about 1.6 mm between neighbouring points: several points in each 3.125 mm cell.
    k_down = (600.0, 0.0, cols / 2, 0.0, 600.0, rows / 2, 0.0, 0.0, 1.0)
    k_tilted = (400.0, 0.0, cols / 2, 0.0, 400.0, rows / 2, 0.0, 0.0, 1.0)
    down = cams.CameraConfig((rows, cols), k_down, (0.5, 0.0, 1.0), tf.euler_to_quat(math.pi, 0.0, 0.0))
    tilted = cams.CameraConfig((rows, cols), k_tilted, (0.5, 0.0, 0.6), tf.euler_to_quat(math.pi - 0.2, 0.1, 0.4))
    views = []
    for plane in (0.97, 0.6):  # metres from each camera to the plane
        color = rng.integers(0, 256, size=(rows, cols, 3), dtype=np.uint8)
        color[rng.random((rows, cols)) < 0.2] = 0  # black points do not count in the colour mean
        depth = np.full((rows, cols), plane, np.float32)  # a plane: many equal z values
        depth[20:50, 30:70] = plane - 0.03  # a box top
        depth[rng.random((rows, cols)) < 0.05] = plane + 0.03  # the table: z = 0, the lower bound, below it
        depth[rng.random((rows, cols)) < 0.02] = 0.0  # no reading
        views.append((color, depth))
    for bounds in (hm.BOUNDS, hm.BOUNDS + np.array([[0.0123], [-0.007], [-0.01]])):
        errors = _compare_fusion(reference_utils, tmp_path, views, [down, tilted], bounds)
        assert errors == {"height_max_abs_error": 0.0, "colour_cells_differing": 0}


def test_cameras_are_the_reference_cameras(reference_utils, tmp_path):
    ref = json.loads(str(reference_utils(tmp_path, "cameras")["configs"]))
    for ours, theirs in [
        *zip(cams.realsense_d415(), ref["realsense"], strict=True),
        (cams.oracle_camera(), ref["oracle"][0]),
    ]:
        assert list(ours.image_size) == theirs["image_size"]
        assert list(ours.intrinsics) == theirs["intrinsics"]
        assert list(ours.position) == theirs["position"]
        assert list(ours.zrange) == theirs["zrange"]
        # Ours are pybullet's getQuaternionFromEuler (as the reference computes them); the reference
        # folder's pybullet stand-in can differ from it in the last bit.
        np.testing.assert_allclose(ours.rotation, theirs["rotation"], rtol=0, atol=1e-15)
        assert theirs["noise"] is False


def test_pixel_conversions_equal_the_reference(reference_utils, tmp_path):
    rng = np.random.default_rng(1)
    rows, cols = hm.heightmap_shape()
    height = rng.uniform(0, 0.28, size=(rows, cols)).astype(np.float32)
    pix = np.stack([rng.integers(0, rows, 2000), rng.integers(0, cols, 2000)], axis=1)
    xyz = np.concatenate(
        [
            rng.uniform(hm.BOUNDS[:, 0], hm.BOUNDS[:, 1], size=(2000, 3)),
            # cell corners, half-cells (rounding ties) and just beside them
            np.array([hm.pix_to_xyz((u, v), 0.0) for u, v in pix[:500]]),
            np.array([hm.pix_to_xyz((u, v), 0.0) for u, v in pix[:500]]) + hm.PIXEL_SIZE / 2,
            np.array([hm.pix_to_xyz((u, v), 0.0) for u, v in pix[:500]]) + np.nextafter(hm.PIXEL_SIZE / 2, 0),
        ]
    )
    ref = reference_utils(
        tmp_path,
        "pixels",
        pix=pix,
        height=height,
        xyz=xyz,
        bounds=hm.BOUNDS,
        pixel_size=np.array(hm.PIXEL_SIZE),
    )
    ours_xyz = np.array([hm.pix_to_xyz(tuple(p), height) for p in pix])
    np.testing.assert_array_equal(ours_xyz, ref["xyz"])
    np.testing.assert_array_equal(np.array([hm.xyz_to_pix(x) for x in xyz]), ref["pix"])


def test_rotations_equal_the_reference(reference_utils, tmp_path):
    """yaw_to_quat is the reference's eulerXYZ_to_quatXYZW((0, 0, yaw)), quat_to_yaw its
    quatXYZW_to_eulerXYZ(q)[2], and the pose of place-rotation bin k (the reference's act():
    eulerXYZ_to_quatXYZW((0, 0, -k * 2 pi / n))) is yaw_to_quat(-k * 2 pi / n)."""
    rng = np.random.default_rng(2)
    yaws = np.concatenate([rng.uniform(-2 * np.pi, 2 * np.pi, 500), [0.0, np.pi, -np.pi, np.pi / 2]])
    tilted = np.stack([rng.normal(0, 0.2, 500), rng.normal(0, 0.2, 500), rng.uniform(-np.pi, np.pi, 500)], axis=1)
    euler = np.concatenate([np.stack([0 * yaws, 0 * yaws, yaws], axis=1), tilted])
    quats = np.concatenate([np.array([tf.yaw_to_quat(y) for y in yaws]), rng.normal(size=(500, 4))])
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    n_rotations = 36
    theta = np.arange(n_rotations) * 2 * np.pi / n_rotations
    ref = reference_utils(tmp_path, "rotations", euler=euler, quat=quats, theta=theta)

    np.testing.assert_array_equal(np.array([tf.yaw_to_quat(y) for y in yaws]), ref["quat"][: len(yaws)])
    ours_yaw = np.array([tf.quat_to_yaw(q) for q in quats])
    np.testing.assert_allclose(ours_yaw, ref["euler"][:, 2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.array([tf.yaw_to_quat(-t) for t in theta]), ref["act_quat"])
    # The reference's sign convention: bin k turns by -k * step about +z (clockwise seen from above).
    assert tf.quat_to_yaw(ref["act_quat"][9]) == pytest.approx(-np.pi / 2)
