"""cliport-convert without the reference code: checkpoints written under the reference's names (from our own
agents, whose nets are the reference's), every kind of bad file, and the converted run used like a native
one. tests/train/test_convert_reference.py converts checkpoints the reference code itself wrote."""

from __future__ import annotations

import json
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.cli import convert as convert_cli
from cliport.cli.common import run_cli
from cliport.models import reference_names
from cliport.utils.run_dir import RunDir

TASK = "place-red-in-green"


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    capsys.readouterr()
    code = 0
    try:
        run_cli(lambda: convert_cli.main(argv))
    except SystemExit as stop:
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def convert_error(capsys, one_error_line):
    """``convert_error(argv)``: cliport-convert's one ``error:`` line (exit status 2) for ``argv``."""

    def run(argv: list[str]) -> str:
        code, _, err = _cli(argv, capsys)
        return one_error_line(code, err, status=2)

    return run


def _lightning(state: dict[str, torch.Tensor], **extra: object) -> dict[str, object]:
    return {
        "epoch": 12,
        "global_step": 2000,
        "pytorch-lightning_version": "1.0.3",
        "state_dict": state,
        "optimizer_states": [],
        "lr_schedulers": [],
        **extra,
    }


@pytest.fixture(scope="module")
def transporter_ckpt(tmp_path_factory) -> tuple[Path, object]:
    """A full-size transporter agent saved as the reference saves it, in a folder named the reference's way."""
    torch.manual_seed(0)
    agent = make_agent("transporter_only", {})
    folder = tmp_path_factory.mktemp("ref") / f"{TASK}-transporter-n10-train" / "checkpoints"
    folder.mkdir(parents=True)
    path = folder / "steps=2000-val_loss=0.00000000.ckpt"
    torch.save(_lightning(reference_names.to_reference("transporter_only", agent.trainable_state_dict())), path)
    return path, agent


def _observation() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    color = rng.integers(0, 60, (320, 160, 3), dtype=np.uint8)
    height = rng.uniform(0, 0.002, (320, 160)).astype(np.float32)
    color[100:112, 60:72], height[100:112, 60:72] = (200, 30, 30), 0.03
    return {"color": color, "height": height}


def test_converted_run_acts_as_the_original_and_records_its_source(transporter_ckpt, tmp_path, capsys) -> None:
    path, original = transporter_ckpt
    run = tmp_path / "run"
    code, out, _ = _cli(["--from", str(path), "--run-dir", str(run)], capsys)
    assert code == 0
    summary = json.loads(out)
    assert summary["reference_agent"] == "transporter" and summary["agent"] == "transporter_only"
    assert summary["task"] == TASK and summary["global_step"] == 2000  # both read from the path and file
    converted = json.loads((run / "converted.json").read_text())
    assert converted["file"] == str(path) and len(converted["sha256"]) == 64
    config = json.loads((run / "config.json").read_text())
    assert config["task"] == TASK and config["n_demos"] == 10 and config["agent_config"]["n_rotations"] == 36
    rd = RunDir(str(run))
    assert rd.checkpoint_steps() == [2000] and rd.resolve("best") == [2000]  # the only checkpoint
    assert os.path.samefile(rd.checkpoint(2000), rd.checkpoint("last"))
    loaded = PickPlaceAgent.from_pretrained(rd.checkpoint(2000))
    obs = _observation()
    ours, theirs = loaded.act(obs), original.act(obs)
    for key in ("pick_pix", "place_pix", "place_bin", "pose0", "pose1"):
        assert ours[key] == theirs[key], key
    np.testing.assert_array_equal(ours["place_heatmap"], theirs["place_heatmap"])


def test_every_bad_file_is_one_line_and_nothing_runs(transporter_ckpt, tmp_path, convert_error, runs_code) -> None:
    path, _ = transporter_ckpt
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.ckpt"
    torch.save(_lightning({"attention.x": torch.zeros(1)}, callbacks=runs_code(f"touch {marker}")), evil)
    msg = convert_error(["--from", str(evil), "--run-dir", str(tmp_path / "r1"), "--task", TASK])
    assert str(evil) in msg and "posix.system" in msg and "refused" in msg
    assert not marker.exists() and not (tmp_path / "r1").exists()

    cut = tmp_path / "cut.ckpt"
    cut.write_bytes(path.read_bytes()[:100_000])
    msg = convert_error(["--from", str(cut), "--run-dir", str(tmp_path / "r2")])
    assert "not a zip-format PyTorch checkpoint" in msg

    other = tmp_path / "resnet.ckpt"
    torch.save(_lightning({"layer1.weight": torch.zeros(2)}), other)
    msg = convert_error(["--from", str(other), "--run-dir", str(tmp_path / "r3"), "--task", TASK])
    assert "not a CLIPort checkpoint" in msg and "clip_lingunet_transporter" in msg

    unet = tmp_path / "unet.ckpt"
    torch.save(_lightning({"attention.attn_stream_one.up1.conv.double_conv.0.weight": torch.zeros(2)}), unet)
    msg = convert_error(["--from", str(unet), "--run-dir", str(tmp_path / "r4"), "--task", TASK])
    assert "agent type cliport does not have" in msg and "supported reference agent types" in msg

    argv = ["--from", str(path), "--run-dir", str(tmp_path / "r5"), "--agent-type", "clip_lingunet_transporter"]
    assert "does not hold the clip_lingunet_transporter agent's nets: they are transporter's" in convert_error(argv)
    assert not (tmp_path / "r5").exists()

    assert "invalid choice" in convert_error(["--from", str(path), "--run-dir", "x", "--agent-type", "rn50"])
    nameless = tmp_path / "steps=1.ckpt"
    nameless.write_bytes(path.read_bytes())
    assert "pass --task" in convert_error(["--from", str(nameless), "--run-dir", str(tmp_path / "r6")])
    (tmp_path / "r7").mkdir()
    (tmp_path / "r7" / "config.json").write_text("{}")
    assert "already holds a run" in convert_error(["--from", str(path), "--run-dir", str(tmp_path / "r7")])


def test_the_safe_loader_keeps_lightning_data_classes(transporter_ckpt, tmp_path, monkeypatch) -> None:
    """Hyper-parameters pickled as omegaconf objects load as inert data (the module is not installed)."""
    path, _ = transporter_ckpt
    module = types.ModuleType("omegaconf")

    class DictConfig(dict):
        pass

    DictConfig.__module__, DictConfig.__qualname__ = "omegaconf", "DictConfig"
    module.DictConfig = DictConfig
    monkeypatch.setitem(sys.modules, "omegaconf", module)
    payload = torch.load(path, weights_only=True)
    payload["hyper_parameters"] = DictConfig(train={"n_rotations": 36})
    with_hp = tmp_path / f"{TASK}-transporter-n10-train" / "last.ckpt"
    with_hp.parent.mkdir()
    torch.save(payload, with_hp)
    monkeypatch.delitem(sys.modules, "omegaconf")
    from cliport.train.convert import convert_checkpoint

    summary = convert_checkpoint(str(with_hp), str(tmp_path / "run"))
    assert summary["agent"] == "transporter_only" and summary["task"] == TASK


@pytest.fixture(scope="module")
def converted_run(transporter_ckpt, tmp_path_factory) -> str:
    from cliport.train.convert import convert_checkpoint

    run = str(tmp_path_factory.mktemp("converted") / "run")
    convert_checkpoint(str(transporter_ckpt[0]), run)
    return run


@pytest.mark.e2e  # the simulator's episodes; the converted agent's actions are checked above
def test_cliport_eval_runs_a_converted_run_end_to_end(converted_run, tmp_path, capsys) -> None:
    from cliport.cli import eval as eval_cli

    capsys.readouterr()
    argv = ["--run-dir", converted_run, "--task", "block-insertion", "--mode", "test", "--n-episodes", "1",
            "--workers", "1", "--camera-scale", "0.5", "--out", str(tmp_path), "--no-progress"]  # fmt: skip
    run_cli(lambda: eval_cli.main(argv))
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["agent"] == "transporter_only" and result["checkpoint"] == 2000 and result["n_episodes"] == 1


@pytest.mark.slow  # a published-size transporter training step and a demo: ~1-2 minutes on 2 CPU cores
def test_cliport_train_resumes_a_converted_run(converted_run, tmp_path, capsys) -> None:
    """One more optimiser step from the converted weights: last.pt moves on, the converted checkpoint stays."""
    from cliport.cli import demos as demos_cli
    from cliport.cli import train as train_cli

    data = str(tmp_path / "data")
    run_cli(lambda: demos_cli.main(["--task", TASK, "--mode", "train", "--n", "1", "--data-dir", data,
                                    "--workers", "1", "--no-progress"]))  # fmt: skip
    rd = RunDir(converted_run)
    before = torch.load(rd.checkpoint(2000), weights_only=True)["state_dict"]
    run_cli(lambda: train_cli.main(["--resume", "--run-dir", converted_run, "--n-steps", "2001", "--n-demos", "1",
                                    "--data-dir", data, "--val-episodes", "0", "--no-progress"]))  # fmt: skip
    last = torch.load(rd.checkpoint("last"), weights_only=True)
    assert last["trainer"]["step"] == 2001 and not os.path.samefile(rd.checkpoint(2000), rd.checkpoint("last"))
    after = torch.load(rd.checkpoint(2000), weights_only=True)["state_dict"]
    assert all(torch.equal(before[k], after[k]) for k in before)  # the converted checkpoint is untouched
    assert any(not torch.equal(before[k], last["state_dict"][k]) for k in before)  # training moved the weights
