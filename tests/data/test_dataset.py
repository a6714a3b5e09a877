import math
import os

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from cliport.data import augment
from cliport.data.dataset import DatasetError, DemoDataset, rotation_bin
from cliport.env.transforms import yaw_to_quat


def test_augmentation_keeps_labels_on_scene_points(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path))
    ds = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=3, augment=True)
    torch.manual_seed(0)
    moved = 0
    for i in range(len(ds)):
        s = ds[i]
        assert tuple(s["color"][tuple(s["pick_pix"])]) == (255, 0, 0)
        assert tuple(s["color"][tuple(s["place_pix"])]) == (0, 255, 0)
        assert s["height"][tuple(s["pick_pix"])] == pytest.approx(0.05, abs=1e-4)
        assert s["place_rot"] == 9  # 90 degrees relative: invariant to the rotation
        moved += int(
            tuple(s["color"].reshape(-1, 3).sum(0))
            != tuple(ds.episode(ds.index[i][0]).color[ds.index[i][1]].reshape(-1, 3).sum(0))
        )
    assert moved > 0


def test_se2_transform_of_pixels_matches_image_warp():
    rng = np.random.default_rng(3)
    for _ in range(20):
        img = np.zeros((320, 160), np.uint8)
        pix = (int(rng.integers(60, 260)), int(rng.integers(30, 130)))
        img[pix[0] - 1 : pix[0] + 2, pix[1] - 1 : pix[1] + 2] = 255
        m = augment.sample_se2(rng, img.shape, [pix])
        out = augment.warp(img, m)
        assert out[augment.transform_pixel(m, pix)] == 255


def test_subset_is_seeded_and_loader_batches(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path), n_episodes=4)
    a = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=2, seed=1)
    b = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=2, seed=1)
    assert a.files == b.files and len(a) == 4
    batch = next(iter(DataLoader(a, batch_size=3, shuffle=True, num_workers=2)))
    assert batch["color"].shape == (3, 320, 160, 3) and batch["color"].dtype == torch.uint8
    assert batch["pick_pix"].shape == (3, 2) and batch["place_rot"].shape == (3,)
    assert len(batch["lang"]) == 3


def test_rotation_bin_convention():
    assert rotation_bin(yaw_to_quat(0.0), yaw_to_quat(math.radians(30)), 36) == 3
    assert rotation_bin(yaw_to_quat(1.0), yaw_to_quat(1.0 - math.radians(10)), 36) == 35


def test_clear_errors(tmp_path, make_synthetic_dataset):
    with pytest.raises(DatasetError, match="place-red-in-green-train"):
        DemoDataset(str(tmp_path), "place-red-in-green")
    folder = make_synthetic_dataset(str(tmp_path), n_episodes=2)
    with pytest.raises(DatasetError, match=f"{folder} has 2 episodes but n_demos=5"):
        DemoDataset(str(tmp_path), "place-red-in-green", n_demos=5)
    with open(os.path.join(folder, "000002.npz"), "r+b") as f:
        f.truncate(100)
    with pytest.raises(DatasetError, match="000002.npz"):
        DemoDataset(str(tmp_path), "place-red-in-green")
    with pytest.raises(DatasetError, match="unknown task"):
        DemoDataset(str(tmp_path), "no-such-task")
