"""cliport-import: synthetic real demonstrations (two top-down RGB-D cameras, nothing rendered) become
episode files that DemoDataset serves; bad inputs are one error line naming episode, step and field."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from cliport.cli.import_demos import entry, main
from cliport.data.dataset import DemoDataset
from cliport.data.episode_io import HEIGHT_UNIT, dataset_dir, episode_path, load_episode
from cliport.deploy.scene import fuse_scene, load_cameras

TASK = "block-insertion"
ROWS, COLS = 40, 80
# Looking straight down from 1 m (camera z -> world -z, y -> -y), one above each half of the workspace.
CAMERAS = [
    {
        "image_size": [ROWS, COLS],
        "intrinsics": [60, 0, COLS / 2, 0, 60, ROWS / 2, 0, 0, 1],
        "position": [0.5, y, 1.0],
        "rotation": [1, 0, 0, 0],
    }
    for y in (-0.25, 0.25)
]
PICK = {"position": [0.45, -0.2, 0.02], "rotation": [0, 0, 0, 1]}
PLACE = {"position": [0.55, 0.2, 0.02], "rotation": [0, 0, 0.7071068, 0.7071068]}


def _views(t: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per camera (rgb, depth): the table at z = 0.01 and a 5 cm block whose place moves with t."""
    views = []
    for i in range(len(CAMERAS)):
        color = np.full((ROWS, COLS, 3), 90, np.uint8)
        depth = np.full((ROWS, COLS), 0.99, np.float32)
        c0 = 20 + 10 * t + 5 * i
        color[15:25, c0 : c0 + 10] = (200, 30, 30)
        depth[15:25, c0 : c0 + 10] = 0.95
        views.append((color, depth))
    return views


def write_demo(root: str, n_episodes: int = 2, n_steps: int = 2, png_depth: bool = False) -> str:
    """DIR/episode-00i/ with cameras.json, steps.json and c{t}{i}.png, d{t}{i}.npy (or 16-bit mm PNG)."""
    for e in range(n_episodes):
        folder = os.path.join(root, f"episode-{e:03d}")
        os.makedirs(folder)
        cams = [dict(c, depth_scale=0.001) if png_depth else c for c in CAMERAS]
        with open(os.path.join(folder, "cameras.json"), "w") as f:
            json.dump(cams, f)
        steps = []
        for t in range(n_steps):
            rgb, dep = [], []
            for i, (color, depth) in enumerate(_views(t)):
                rgb.append(f"c{t}{i}.png")
                cv2.imwrite(os.path.join(folder, rgb[-1]), color[..., ::-1])
                if png_depth:
                    dep.append(f"d{t}{i}.png")
                    cv2.imwrite(os.path.join(folder, dep[-1]), np.round(depth * 1000).astype(np.uint16))
                else:
                    dep.append(f"d{t}{i}.npy")
                    np.save(os.path.join(folder, dep[-1]), depth)
            steps.append({"rgb": rgb, "depth": dep, "pick": PICK, "place": PLACE, "instruction": f"step {t}"})
        with open(os.path.join(folder, "steps.json"), "w") as f:
            json.dump(steps, f)
    return root


def test_import_loads_with_dataset_and_resumes(tmp_path, capsys):
    src = write_demo(str(tmp_path / "src"))
    data = str(tmp_path / "data")
    main(["--from", src, "--task", TASK, "--data-dir", data])
    summary = json.loads(capsys.readouterr().out)
    assert (summary["episodes"], summary["imported"], summary["skipped"], summary["steps"]) == (2, 2, 0, 4)
    assert summary["seeds"] == [0, 2]  # train seeds of indices 0 and 1

    folder = dataset_dir(data, TASK, "train")
    ep = load_episode(episode_path(folder, 2))
    cams = load_cameras(os.path.join(src, "episode-001", "cameras.json"))
    for t in range(2):
        fused, _ = fuse_scene(_views(t), cams)
        np.testing.assert_array_equal(ep.color[t], fused.color)
        np.testing.assert_allclose(ep.height[t], fused.height, atol=HEIGHT_UNIT)
    assert ep.height.max() == pytest.approx(0.05, abs=1e-3) and ep.color.max() == 200
    np.testing.assert_allclose(ep.pose0[0], PICK["position"] + PICK["rotation"])
    np.testing.assert_allclose(ep.pose1[1], PLACE["position"] + PLACE["rotation"], atol=1e-6)
    np.testing.assert_allclose(ep.reward, [0.5, 0.5])
    assert ep.lang_goal == ["step 0", "step 1"]
    assert ep.meta["imported"] is True and ep.meta["camera_scale"] is None and ep.meta["seed"] == 2
    assert ep.meta["source"] == os.path.abspath(os.path.join(src, "episode-001"))

    ds = DemoDataset(data, TASK, "train")
    assert len(ds) == 4
    sample = ds[0]
    assert sample["color"].shape == (320, 160, 3) and sample["pose0"].shape == (7,)

    stamp = os.path.getmtime(episode_path(folder, 0))
    os.remove(episode_path(folder, 2))
    main(["--from", src, "--task", TASK, "--data-dir", data])
    summary = json.loads(capsys.readouterr().out)
    assert (summary["imported"], summary["skipped"], summary["steps"]) == (1, 1, 2)
    assert os.path.getmtime(episode_path(folder, 0)) == stamp


def test_png_depth_and_moved_bounds(tmp_path, capsys):
    """Millimetre PNG depth; bounds moved by +0.1 m in x move the poses into the simulator's frame."""
    src = write_demo(str(tmp_path / "src"), n_episodes=1, n_steps=1, png_depth=True)
    data = str(tmp_path / "data")
    bounds = ["--bounds", "0.35", "0.85", "-0.5", "0.5", "0", "0.28"]
    main(["--from", src, "--task", TASK, "--data-dir", data, "--mode", "val", *bounds])
    assert json.loads(capsys.readouterr().out)["seeds"] == [1]
    ep = load_episode(episode_path(dataset_dir(data, TASK, "val"), 1))
    np.testing.assert_allclose(ep.pose0[0, :3], [0.35, -0.2, 0.02])
    assert ep.height.max() == pytest.approx(0.05, abs=1e-3)


def _no_steps(folder):
    os.remove(os.path.join(folder, "steps.json"))


def _edit_step(change):
    def edit(folder):
        path = os.path.join(folder, "steps.json")
        with open(path) as f:
            steps = json.load(f)
        change(steps[1])
        with open(path, "w") as f:
            json.dump(steps, f)

    return edit


BAD = {
    "missing steps.json": (_no_steps, ["episode-001", "steps.json"]),
    "missing pick": (_edit_step(lambda s: s.pop("pick")), ["episode-001", "step 1", "field pick"]),
    "3 rotation numbers": (
        _edit_step(lambda s: s["place"].update(rotation=[0, 0, 1])),
        ["episode-001", "step 1", "field place.rotation"],
    ),
    "more depth than cameras": (
        _edit_step(lambda s: s["depth"].append(s["depth"][0])),
        ["episode-001", "step 1", "field depth", "3 file(s)", "2 camera(s)"],
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_one_error_line_no_file(case, tmp_path, monkeypatch, capsys, one_error_line):
    src = write_demo(str(tmp_path / "src"))
    spoil, words = BAD[case]
    spoil(os.path.join(src, "episode-001"))
    data = str(tmp_path / "data")
    monkeypatch.setattr("sys.argv", ["cliport-import", "--from", src, "--task", TASK, "--data-dir", data])
    with pytest.raises(SystemExit) as exit_info:
        entry()
    one_error_line(exit_info.value.code, capsys.readouterr().err, *words, status=2)
    folder = dataset_dir(data, TASK, "train")
    assert not os.path.exists(folder) or os.listdir(folder) == []


def test_unknown_task_and_bad_image(tmp_path, monkeypatch, capsys):
    src = write_demo(str(tmp_path / "src"), n_episodes=1)
    monkeypatch.setattr(
        "sys.argv", ["cliport-import", "--from", src, "--task", "no-such-task", "--data-dir", str(tmp_path)]
    )
    with pytest.raises(SystemExit):
        entry()
    assert "unknown task 'no-such-task'" in capsys.readouterr().err
    # An image of the wrong size is found while reading, before the episode is written.
    cv2.imwrite(os.path.join(src, "episode-000", "c10.png"), np.zeros((10, 10, 3), np.uint8))
    data = str(tmp_path / "data")
    monkeypatch.setattr("sys.argv", ["cliport-import", "--from", src, "--task", TASK, "--data-dir", data])
    with pytest.raises(SystemExit):
        entry()
    err = capsys.readouterr().err
    assert "episode-000" in err and "step 1" in err and "field rgb/depth" in err and "image_size" in err
    assert os.listdir(dataset_dir(data, TASK, "train")) == []
