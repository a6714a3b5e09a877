"""Our fused top-down maps, pixel <-> position conversions and yaw quaternions equal the reference CLIPort's
for the same inputs (its utils run in a subprocess: tests/reference_oracle.py; skipped without it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from cliport.env import heightmap as hm
from cliport.env.transforms import quat_to_yaw, yaw_to_quat


@pytest.mark.parametrize(("task", "seed"), [("put-block-in-bowl-seen-colors", 0), ("packing-boxes", 2)])
def test_same_camera_images_give_the_references_maps(reference_oracle, tmp_path, task, seed) -> None:
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    config = EnvConfig.defaults(raw_images=True)
    with Environment(config, task=tasks.make(task, "train")) as env:
        obs = env.reset(seed=seed)
        cameras = list(env.camera_configs)
    views = obs["cameras"]
    rng = np.random.default_rng(seed)
    pixels = np.stack([rng.integers(0, 320, 200), rng.integers(0, 160, 200)], axis=1)
    positions = np.stack([rng.uniform(0.25, 0.75, 200), rng.uniform(-0.5, 0.5, 200), np.zeros(200)], axis=1)
    yaws = np.linspace(-2 * np.pi, 2 * np.pi, 73)
    request = {
        "color": torch.from_numpy(np.stack([v["color"] for v in views])),
        "depth": torch.from_numpy(np.stack([v["depth"] for v in views])),
        "cameras": [dataclasses.asdict(c) for c in cameras],
        "height": torch.from_numpy(obs["height"]),
        "pixels": torch.from_numpy(pixels),
        "positions": torch.from_numpy(positions),
        "yaws": torch.from_numpy(yaws),
    }
    torch.save(request, tmp_path / "request.pt")
    reference_oracle("geometry", str(tmp_path / "request.pt"), str(tmp_path / "out.pt"))
    ref = torch.load(tmp_path / "out.pt", weights_only=True)

    fused = hm.fuse_cameras([(v["color"], v["depth"]) for v in views], cameras)
    assert np.array_equal(fused.color, ref["color"].numpy())  # colour exactly
    assert float(np.abs(fused.height - ref["height"].numpy()).max()) <= 1e-6  # height within 1e-6 m
    assert np.array_equal(fused.color, obs["color"]) and np.array_equal(fused.height, obs["height"])
    assert (fused.height > 0).mean() > 0.5  # a real scene, not an empty map

    xyz = np.array([hm.pix_to_xyz(tuple(p), obs["height"]) for p in pixels])
    np.testing.assert_array_equal(xyz, ref["xyz"].numpy())
    assert [hm.xyz_to_pix(p) for p in positions] == [tuple(p) for p in ref["pix"].tolist()]
    np.testing.assert_allclose(np.array([yaw_to_quat(y) for y in yaws]), ref["quat"].numpy(), rtol=0, atol=1e-12)
    ref_yaws = ref["euler"].numpy()[:, 2]
    ours = np.array([quat_to_yaw(q) for q in ref["quat"].numpy()])
    np.testing.assert_allclose(np.cos(ours - ref_yaws), 1.0, rtol=0, atol=1e-12)
