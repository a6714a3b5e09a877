"""cliport-predict and Predictor: camera files of a simulator scene give the simulator's own fused map and
the same action as the agent acting on the simulator's observation."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from cliport.agents import PickPlaceAgent
from cliport.cli import predict as predict_cli
from cliport.cli.common import run_cli
from cliport.deploy import Predictor
from cliport.utils.run_dir import RunDir


def _predict(argv: list[str], capsys) -> dict:
    capsys.readouterr()
    run_cli(lambda: predict_cli.main(argv))
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def _argv(run_dir: str, files: dict, out: str, lang: str, *extra: str) -> list[str]:
    return [
        "--run-dir", run_dir, "--rgb", *files["rgb"], "--depth", *files["depth"], "--cameras", files["cameras"],
        "--lang", lang, "--device", "cpu", "--out", out, *extra,
    ]  # fmt: skip


@pytest.fixture(scope="module")
def sim_action(sim_scene, tiny_run):
    """The agent acting on the simulator's own observation (the best checkpoint, step 1)."""
    obs, _, lang = sim_scene
    agent = PickPlaceAgent.from_pretrained(RunDir(tiny_run).checkpoint(1))
    return agent.act({"color": obs["color"], "height": obs["height"]}, lang)


def test_float_depth_files_fuse_identically_and_give_the_same_action(
    sim_scene, sim_action, tiny_run, tmp_path, capsys, scene_files
):
    obs, cameras, lang = sim_scene
    files = scene_files(obs, cameras, str(tmp_path / "scene"))
    out = str(tmp_path / "out")
    result = _predict(_argv(tiny_run, files, out, lang), capsys)
    stem = os.path.join(out, os.path.basename(result["heatmaps"])[: -len("-heatmaps.png")])
    # The fused map written next to the prediction is the simulator's observation, bit for bit.
    assert np.array_equal(np.load(stem + "-height.npy"), obs["height"])
    assert result["pick"]["pixel"] == list(sim_action["pick_pix"])
    assert result["place"]["pixel"] == list(sim_action["place_pix"])
    assert result["place"]["rotation_bin"] == round(sim_action["place_rot"] / (2 * np.pi / 4)) % 4
    assert result["pick"]["xyz"] == pytest.approx(list(sim_action["pose0"][0]), abs=1e-6)
    assert result["place"]["quat"] == pytest.approx(list(sim_action["pose1"][1]), abs=1e-6)
    assert result["instruction"] == lang and result["checkpoint"] == RunDir(tiny_run).checkpoint(1)
    assert os.path.getsize(result["heatmaps"]) > 0 and os.path.isfile(stem + ".json")
    # --heightmap takes the fused map instead and gives the same action.
    again = _predict(
        ["--run-dir", tiny_run, "--heightmap", stem + "-color.png", stem + "-height.npy", "--lang", lang,
         "--device", "cpu", "--out", out],
        capsys,
    )  # fmt: skip
    assert again["pick"] == result["pick"] and again["place"] == result["place"]


def test_sixteen_bit_png_depth_with_depth_scale_within_a_pixel(
    sim_scene, sim_action, tiny_run, tmp_path, capsys, scene_files
):
    obs, cameras, lang = sim_scene
    files = scene_files(obs, cameras, str(tmp_path / "scene"), png_scale=0.0001)
    out = str(tmp_path / "out")
    result = _predict(_argv(tiny_run, files, out, lang, "--checkpoint", "last"), capsys)
    height = np.load(result["heatmaps"][: -len("-heatmaps.png")] + "-height.npy")
    both = (height > 0) & (obs["height"] > 0)
    assert both.sum() > 0.95 * (obs["height"] > 0).sum()  # 0.1 mm depth steps move a few edge points only
    assert np.mean(np.abs(height - obs["height"])[both] > 0.002) < 0.01
    for key, pix in (("pick", sim_action["pick_pix"]), ("place", sim_action["place_pix"])):
        assert np.abs(np.subtract(result[key]["pixel"], pix)).max() <= 1, (key, result[key]["pixel"], pix)


def test_python_api_matches_the_simulator(sim_scene, sim_action, tiny_run):
    obs, cameras, lang = sim_scene
    predictor = Predictor(tiny_run, checkpoint="best", device="cpu")
    images = [(img["color"], img["depth"]) for img in obs["cameras"]]
    prediction = predictor.predict(images, cameras, lang)
    assert np.array_equal(prediction.obs["color"], obs["color"])
    assert np.array_equal(prediction.obs["height"], obs["height"])
    assert np.array_equal(prediction.act["pick_heatmap"], sim_action["pick_heatmap"])
    assert np.array_equal(prediction.act["place_heatmap"], sim_action["place_heatmap"])
    assert tuple(prediction.pick["pixel"]) == sim_action["pick_pix"]
    assert tuple(prediction.place["pixel"]) == sim_action["place_pix"]
    assert prediction.notes == ["transporter_only ignores language: the instruction cannot change what it does"]
    # A moved workspace moves the poses with it (same pixels, shifted metres).
    moved = Predictor(tiny_run, checkpoint="1", device="cpu", bounds=[0.35, 0.85, -0.4, 0.6, 0.0, 0.28])
    cams = [dict(c.__dict__, position=(c.position[0] + 0.1, c.position[1] + 0.1, c.position[2])) for c in cameras]
    shifted = moved.predict(images, cams, lang)
    # The same map up to boundary points: binning floors world points rounded to float32 (the reference's
    # rule), so a frame moved by 0.1 m puts a few of them (0.3% of cells here) in the neighbouring cell.
    assert np.mean(shifted.obs["height"] != obs["height"]) < 0.01
    assert np.mean((shifted.obs["color"] != obs["color"]).any(axis=-1)) < 0.01
    assert shifted.pick["pixel"] == prediction.pick["pixel"]
    assert shifted.pick["xyz"][:2] == pytest.approx([c + 0.1 for c in prediction.pick["xyz"][:2]], abs=1e-6)
