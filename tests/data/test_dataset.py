import math
import os

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from cliport.data import augment
from cliport.data.dataset import DatasetError, DemoDataset
from cliport.env import heightmap as hm
from cliport.env.transforms import quat_to_yaw, yaw_to_quat


def test_augmentation_keeps_labels_on_scene_points(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path))
    ds = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=3, augment=True)
    torch.manual_seed(0)
    moved = 0
    for i in range(len(ds)):
        s = ds[i]
        pick, place = hm.xyz_to_pix(s["pose0"][:3]), hm.xyz_to_pix(s["pose1"][:3])
        assert tuple(s["color"][pick]) == (255, 0, 0)
        assert tuple(s["color"][place]) == (0, 255, 0)
        assert s["height"][pick] == pytest.approx(0.05, abs=1e-4)
        relative = (quat_to_yaw(s["pose1"][3:]) - quat_to_yaw(s["pose0"][3:])) % (2 * math.pi)
        assert relative == pytest.approx(math.pi / 2)  # invariant to the rotation
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
    assert batch["pose0"].shape == (3, 7) and batch["pose1"].shape == (3, 7)
    assert len(batch["lang"]) == 3


def test_pose_transform_matches_pixel_transform_and_turns_the_yaw():
    rng = np.random.default_rng(5)
    for _ in range(50):
        pix = (int(rng.integers(0, 320)), int(rng.integers(0, 160)))
        yaw = float(rng.uniform(-math.pi, math.pi))
        pose = np.array([*hm.pix_to_xyz(pix, np.zeros((320, 160), np.float32)), *yaw_to_quat(yaw)])
        m = augment.sample_se2(rng, (320, 160), [pix])
        moved = augment.transform_pose(m, pose)
        assert hm.xyz_to_pix(moved[:3]) == augment.transform_pixel(m, pix)
        turn = math.atan2(m[1, 0], m[0, 0])
        assert math.cos(quat_to_yaw(moved[3:]) - yaw - turn) == pytest.approx(1.0)


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


def test_rotation_aug_zero_keeps_the_recorded_yaw_and_only_shifts(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path))
    plain = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=3, augment=False)
    still = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=3, rotation_aug=0.0)
    turned = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=3)
    shifted = 0
    turns = []
    for i in range(len(plain)):
        ref, s, t = plain[i], still[i], turned[i]
        for key in ("pose0", "pose1"):
            assert quat_to_yaw(s[key][3:]) == pytest.approx(quat_to_yaw(ref[key][3:]), abs=1e-9)
        turns.append(abs(quat_to_yaw(t["pose0"][3:]) - quat_to_yaw(ref["pose0"][3:])))
        # The image is the recorded one moved by the pick pixel's integer offset, nothing else.
        du, dv = np.subtract(hm.xyz_to_pix(s["pose0"][:3]), hm.xyz_to_pix(ref["pose0"][:3]))
        assert np.subtract(hm.xyz_to_pix(s["pose1"][:3]), hm.xyz_to_pix(ref["pose1"][:3])).tolist() == [du, dv]
        h, w = ref["height"].shape
        src = ref["color"][max(0, -du) : h - max(0, du), max(0, -dv) : w - max(0, dv)]
        dst = s["color"][max(0, du) : h + min(0, du), max(0, dv) : w + min(0, dv)]
        assert np.array_equal(src, dst)
        shifted += (du, dv) != (0, 0)
    assert shifted >= len(plain) - 1  # shifts stay on
    assert max(turns) > 0.1  # the default still rotates


def test_rotation_aug_is_a_training_setting():
    from cliport.errors import ConfigError
    from cliport.train.config import TrainConfig

    base = {"agent": "transporter_only", "task": "block-insertion"}
    assert TrainConfig.build(base).rotation_aug == 60.0
    assert TrainConfig.build({**base, "rotation_aug": 0.0}).rotation_aug == 0.0
    with pytest.raises(ConfigError, match="rotation_aug"):
        TrainConfig.build({**base, "rotation_aug": -5.0})
    saved = TrainConfig.build(base).to_dict()
    del saved["rotation_aug"]  # a run saved before the setting existed trained with 60
    assert TrainConfig.from_saved(saved).rotation_aug == 60.0


def test_every_instruction_makes_each_recorded_instruction_a_sample(tmp_path, make_variant_dataset):
    make_variant_dataset(str(tmp_path))
    one = DemoDataset(str(tmp_path), "put-one-block-in-bowl-seen-colors", augment=False)
    assert len(one) == 1 and one.instructions() == ["put the gray block in the red bowl"]
    every = DemoDataset(str(tmp_path), "put-one-block-in-bowl-seen-colors", augment=False, every_instruction=True)
    samples = {every[i]["lang"]: every[i] for i in range(len(every))}
    assert len(every) == 3 and sorted(samples) == every.instructions()
    for colour, x in (("gray", 0.3), ("blue", 0.4), ("green", 0.5)):
        sample = samples[f"put the {colour} block in the red bowl"]
        assert sample["pose0"][0] == pytest.approx(x) and sample["pose1"][:2] == pytest.approx([x, 0.2])


def test_every_instruction_needs_demos_that_record_them(tmp_path, make_synthetic_dataset):
    folder = make_synthetic_dataset(str(tmp_path), n_episodes=1)
    with pytest.raises(DatasetError, match=f"{folder}.*cliport-demos --every-instruction"):
        DemoDataset(str(tmp_path), "place-red-in-green", every_instruction=True)


def test_contrasting_instructions_name_another_pick_and_another_place_and_share_an_augmentation(
    tmp_path, make_two_bowl_dataset
):
    make_two_bowl_dataset(str(tmp_path))
    ds = DemoDataset(str(tmp_path), "put-one-block-in-bowl-seen-colors", every_instruction=True)
    lang = [ds.sample(i, augment=False)["lang"] for i in range(len(ds))]
    pairs = {lang[i]: [lang[j] for j in partners] for i, partners in enumerate(ds.contrasting())}
    assert pairs == {
        "put the gray block in the red bowl": ["put the blue block in the blue bowl"],
        "put the gray block in the blue bowl": ["put the blue block in the red bowl"],
        "put the blue block in the red bowl": ["put the gray block in the blue bowl"],
        "put the blue block in the blue bowl": ["put the gray block in the red bowl"],
    }
    first, second = lang.index("put the gray block in the red bowl"), lang.index("put the blue block in the blue bowl")
    a, b, other = ds[(first, 7)], ds[(second, 7)], ds[(second, 8)]
    assert np.array_equal(a["color"], b["color"]) and np.array_equal(a["height"], b["height"])
    assert not np.array_equal(b["color"], other["color"]), "another seed, another transform"
    # One rigid transform moved both: the targets are as far apart as recorded.
    assert np.linalg.norm(a["pose0"][:2] - b["pose0"][:2]) == pytest.approx(0.15, abs=1e-3)
    assert np.linalg.norm(a["pose1"][:2] - b["pose1"][:2]) == pytest.approx(np.hypot(0.3, 0.4), abs=1e-3)
    one = DemoDataset(str(tmp_path), "put-one-block-in-bowl-seen-colors")
    assert one.contrasting() == [[]], "without every_instruction a scene has one instruction"
