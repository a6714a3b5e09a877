"""A 2-step cliport-train writes TensorBoard events (losses, learning rate, samples/s; validation score and
success with intervals), keeps metrics.csv, and leaves safetensors weights that from_pretrained loads;
cliport-eval logs its summary too."""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from cliport.agents import PickPlaceAgent
from cliport.cli import demos as demos_cli
from cliport.cli import eval as eval_cli
from cliport.cli import train as train_cli
from cliport.cli.common import run_cli
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir

TASK = "block-insertion"
TINY = ["--width", "0.125", "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32"]
TRAIN_TAGS = {"train/loss", "train/pick_loss", "train/place_loss", "train/learning_rate", "train/samples_per_second"}
RESULT_TAGS = ("mean_score", "mean_score_ci95_low", "mean_score_ci95_high", "success", "success_ci95_low",
               "success_ci95_high")  # fmt: skip


def _run(main, argv):
    run_cli(lambda: main(argv))


def _scalars(folder: str) -> dict[str, list[tuple[int, float]]]:
    events = EventAccumulator(folder)
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> str:
    """A 2-step transporter_only run with a checkpoint at steps 1 and 2, each validated on one episode."""
    root = tmp_path_factory.mktemp("tb")
    data, run = str(root / "data"), str(root / "run")
    _run(demos_cli.main, ["--task", TASK, "--n", "2", "--data-dir", data, "--camera-scale", "0.5", "--no-progress"])
    _run(train_cli.main, [
        "--agent", "transporter_only", "--task", TASK, "--n-demos", "2", "--n-steps", "2", "--batch-size", "1",
        "--data-dir", data, "--run-dir", run, "--num-workers", "0", "--val-episodes", "1", "--val-workers", "1",
        "--camera-scale", "0.5", "--checkpoint-steps", "1", "--checkpoint-every", "0", "--log-every", "1",
        "--no-progress", *TINY,
    ])  # fmt: skip
    return run


def test_training_writes_the_losses_and_keeps_metrics_csv(run_dir) -> None:
    scalars = _scalars(RunDir(run_dir).tensorboard)
    assert TRAIN_TAGS <= set(scalars)
    assert not any(tag.startswith("gpu/") for tag in scalars)  # GPU memory only on CUDA
    with open(RunDir(run_dir).metrics) as f:
        rows = list(csv.DictReader(f))
    assert [int(r["step"]) for r in rows] == [1, 2]
    for tag in ("loss", "pick_loss", "place_loss"):
        assert [step for step, _ in scalars[f"train/{tag}"]] == [1, 2]
        assert [v for _, v in scalars[f"train/{tag}"]] == pytest.approx([float(r[tag]) for r in rows], rel=1e-4)
    assert [v for _, v in scalars["train/learning_rate"]] == pytest.approx([1e-4, 1e-4])  # transporter_only's lr
    assert all(v > 0 for _, v in scalars["train/samples_per_second"])


def test_validation_writes_score_and_success_with_intervals(run_dir) -> None:
    val = read_json(RunDir(run_dir).val)
    scalars = _scalars(RunDir(run_dir).tensorboard_val)
    assert {f"val/{t}" for t in RESULT_TAGS} <= set(scalars)
    for step in ("1", "2"):
        row = val["checkpoints"][step]
        logged = {t: dict(scalars[f"val/{t}"])[int(step)] for t in RESULT_TAGS}
        assert logged["mean_score"] == pytest.approx(row["mean_score"])
        assert (logged["mean_score_ci95_low"], logged["mean_score_ci95_high"]) == pytest.approx(row["ci95"])
        assert logged["success"] == pytest.approx(100 * row["success_rate"])
        assert (logged["success_ci95_low"], logged["success_ci95_high"]) == pytest.approx(row["success_ci95"])
        assert row["success_ci95"][0] <= 100 * row["success_rate"] <= row["success_ci95"][1]


def test_evaluation_writes_its_summary(run_dir, capsys) -> None:
    capsys.readouterr()
    _run(eval_cli.main, ["--run-dir", run_dir, "--checkpoint", "2", "--n-episodes", "1", "--workers", "1",
                         "--no-progress"])  # fmt: skip
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    scalars = _scalars(os.path.join(RunDir(run_dir).eval_dir, "tensorboard"))
    assert dict(scalars[f"eval/{TASK}/test/mean_score"]) == {2: pytest.approx(summary["mean_score"])}
    assert dict(scalars[f"eval/{TASK}/test/success_ci95_high"]) == {2: pytest.approx(summary["success_ci95"][1])}


def test_run_folder_holds_safetensors_that_from_pretrained_loads(run_dir) -> None:
    from safetensors.torch import load_file

    run = RunDir(run_dir)
    assert os.path.isfile(run.weights(1)) and os.path.isfile(run.weights(2))
    assert os.path.samefile(run.model_weights, run.weights(2))  # the newest scheduled checkpoint
    original = PickPlaceAgent.from_pretrained(run.checkpoint(2))
    weights = load_file(run.model_weights)
    assert weights.keys() == original.trainable_state_dict().keys()
    for key, value in original.trainable_state_dict().items():
        torch.testing.assert_close(weights[key], value, rtol=0, atol=0)

    agent = PickPlaceAgent.from_pretrained(run_dir)
    rng = np.random.default_rng(1)
    obs = {"color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8),
           "height": rng.uniform(0, 0.1, (320, 160)).astype(np.float32)}  # fmt: skip
    a, b = original.act(obs), agent.act(obs)
    assert (a["pick_pix"], a["place_pix"], a["place_bin"]) == (b["pick_pix"], b["place_pix"], b["place_bin"])
    np.testing.assert_array_equal(a["pick_heatmap"], b["pick_heatmap"])
    np.testing.assert_array_equal(a["place_heatmap"], b["place_heatmap"])
    best = PickPlaceAgent.from_pretrained(run_dir, checkpoint="best")  # val.json's choice, from its .safetensors
    chosen = PickPlaceAgent.from_pretrained(run.checkpoint(read_json(run.val)["best_step"]))
    for key, value in chosen.trainable_state_dict().items():
        torch.testing.assert_close(best.trainable_state_dict()[key], value, rtol=0, atol=0)
