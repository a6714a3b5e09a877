"""Every bad input to cliport-predict is one clear `error:` line and exit status 2 (found before the agent
predicts: the run needs no training)."""

from __future__ import annotations

import dataclasses
import json
import os

import cv2
import numpy as np
import pytest

from cliport.cli import predict as predict_cli
from cliport.cli.common import run_cli


@pytest.fixture(scope="module")
def files(sim_scene, tmp_path_factory):
    obs, cameras, _ = sim_scene
    folder = str(tmp_path_factory.mktemp("scene"))
    paths = {"rgb": [], "depth": [], "cameras": os.path.join(folder, "cameras.json")}
    for i, img in enumerate(obs["cameras"]):
        paths["rgb"].append(os.path.join(folder, f"c{i}.png"))
        cv2.imwrite(paths["rgb"][-1], img["color"][..., ::-1])
        paths["depth"].append(os.path.join(folder, f"d{i}.npy"))
        np.save(paths["depth"][-1], img["depth"])
    with open(paths["cameras"], "w") as f:
        json.dump([dataclasses.asdict(c) for c in cameras], f)
    paths["cams"] = [dataclasses.asdict(c) for c in cameras]
    paths["folder"] = folder
    return paths


@pytest.fixture
def predict_error(capsys, one_error_line):
    """``predict_error(argv)``: cliport-predict's one ``error:`` line (exit status 2) for ``argv``."""

    def run(argv: list[str]) -> str:
        capsys.readouterr()
        with pytest.raises(SystemExit) as stop:
            run_cli(lambda: predict_cli.main(argv))
        return one_error_line(stop.value.code, capsys.readouterr().err, status=2)

    return run


def _argv(run_dir, rgb, depth, cameras, *extra):
    return [
        "--run-dir", run_dir, "--rgb", *rgb, "--depth", *depth, "--cameras", cameras, "--lang", "pick it",
        "--device", "cpu", "--out", "/tmp/unused-cliport-predict", *extra,
    ]  # fmt: skip


def _cameras(files, tmp_path, edit) -> str:
    cams = json.loads(json.dumps(files["cams"]))
    edit(cams)
    path = str(tmp_path / "cameras.json")
    with open(path, "w") as f:
        json.dump(cams, f)
    return path


def test_count_mismatch(files, untrained_run, predict_error):
    msg = predict_error(_argv(untrained_run, files["rgb"][:2], files["depth"], files["cameras"]))
    assert "2 --rgb image(s), 3 --depth image(s) and 3 camera(s)" in msg


def test_image_size_not_the_cameras(files, untrained_run, tmp_path, predict_error):
    cams = _cameras(files, tmp_path, lambda c: c[1].update(image_size=[480, 640]))
    msg = predict_error(_argv(untrained_run, files["rgb"], files["depth"], cams))
    assert "c1.png (camera 1) is 240 x 320" in msg and "image_size is [480, 640]" in msg


def test_millimetres_given_as_metres(files, untrained_run, tmp_path, predict_error):
    depth = list(files["depth"])
    depth[2] = str(tmp_path / "mm.npy")
    np.save(depth[2], np.load(files["depth"][2]) * 1000.0)
    msg = predict_error(_argv(untrained_run, files["rgb"], depth, files["cameras"]))
    assert "mm.npy (camera 2) has a median of" in msg and "metres" in msg and "depth_scale" in msg


def test_integer_png_without_depth_scale(files, untrained_run, tmp_path, predict_error):
    depth = list(files["depth"])
    depth[0] = str(tmp_path / "d0.png")
    cv2.imwrite(depth[0], np.clip(np.load(files["depth"][0]) * 1000, 0, 65535).astype(np.uint16))
    msg = predict_error(_argv(untrained_run, files["rgb"], depth, files["cameras"]))
    assert "d0.png holds integers (uint16) but camera 0 has no depth_scale" in msg
    cams = _cameras(files, tmp_path, lambda c: c[0].update(depth_scale=1.0))  # metres per unit: 1000x too large
    msg = predict_error(_argv(untrained_run, files["rgb"], depth, cams))
    assert "check depth_scale 1 of camera 0" in msg


def test_cameras_that_see_nothing(files, untrained_run, tmp_path, predict_error):
    def away(cams):
        for c in cams:
            c["position"][2] += 5.0

    msg = predict_error(_argv(untrained_run, files["rgb"], files["depth"], _cameras(files, tmp_path, away)))
    assert "fused map is empty" in msg
    assert all(f"camera {i} (" in msg for i in range(3))


@pytest.mark.parametrize(
    "edit, expected",
    [
        (lambda c: c[1].update(rotation=[0, 0, 1]), "camera 1: field rotation must be a quaternion [x, y, z, w]"),
        (lambda c: c[2].pop("intrinsics"), "camera 2: missing field(s) intrinsics"),
        (lambda c: c[0].update(quaternion=[0, 0, 0, 1]), "camera 0: unknown field(s) quaternion"),
        (lambda c: c[0].update(intrinsics=[[450, 0, 320], [0, 450, 240]]), "camera 0: field intrinsics must be 3x3"),
        (lambda c: c[2].update(position="front"), "camera 2: field position must be [x, y, z]"),
        (lambda c: c[1].update(depth_scale=-1), "camera 1: field depth_scale must be a positive number"),
        (lambda c: c[0].update(rotation=[0, 0, 0, 2]), "camera 0: field rotation must be a unit quaternion"),
        (lambda c: c.clear(), "must hold a non-empty list"),
    ],
)
def test_malformed_cameras_json(files, untrained_run, tmp_path, predict_error, edit, expected):
    msg = predict_error(_argv(untrained_run, files["rgb"], files["depth"], _cameras(files, tmp_path, edit)))
    assert expected in msg


def test_other_bad_input(files, untrained_run, tmp_path, predict_error):
    bad_json = tmp_path / "broken.json"
    bad_json.write_text("[{")
    assert "is not valid JSON" in predict_error(_argv(untrained_run, files["rgb"], files["depth"], str(bad_json)))
    args = _argv(untrained_run, files["rgb"], files["depth"], files["cameras"])
    assert "either --heightmap or" in predict_error([*args, "--heightmap", "a.png", "b.npy"])
    assert "--bounds must span 0.5 m in x" in predict_error([*args, "--bounds", "0", "1", "-0.5", "0.5", "0", "0.3"])
    assert "--checkpoint must be best, last or one of" in predict_error([*args, "--checkpoint", "7"])
    assert "run folder not found" in predict_error(["--run-dir", str(tmp_path / "nope"), *args[2:]])
    missing = _argv(untrained_run, ["x.png", *files["rgb"][1:]], files["depth"], files["cameras"])
    assert "colour image not found" in predict_error(missing)
