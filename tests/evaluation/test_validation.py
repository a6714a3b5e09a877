"""Validation after training and beside it (a background process) give the same val.json."""

import pytest

from cliport.cli import train as train_cli
from cliport.cli.common import run_cli
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir


def _train(data_dir: str, run_dir: str, mode: str) -> None:
    argv = [
        "--agent", "transporter_only", "--task", "place-red-in-green", "--n-demos", "2", "--n-steps", "4",
        "--batch-size", "1", "--data-dir", data_dir, "--run-dir", run_dir, "--num-workers", "0",
        "--val-episodes", "1", "--val-workers", "1", "--val-mode", mode, "--camera-scale", "0.5",
        "--checkpoint-steps", "2", "--checkpoint-every", "0", "--no-progress", "--device", "cpu",
        "--width", "0.125", "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32",
    ]  # fmt: skip
    run_cli(lambda: train_cli.main(argv))


@pytest.mark.e2e
def test_validation_beside_training_matches_validation_after_it(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    after, beside = str(tmp_path / "after"), str(tmp_path / "beside")
    _train(str(tmp_path), after, "after")
    _train(str(tmp_path), beside, "beside")
    a, b = read_json(RunDir(after).val), read_json(RunDir(beside).val)
    assert set(a["checkpoints"]) == {"2", "4"} and a == b


def test_bad_val_mode_is_one_line(tmp_path, capsys, one_error_line):
    with pytest.raises(SystemExit) as stop:
        _train(str(tmp_path), str(tmp_path / "run"), "sometimes")
    err = one_error_line(stop.value.code, capsys.readouterr().err, status=2)
    assert err == "error: val_mode must be auto, after or beside, got 'sometimes'"


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, make_synthetic_dataset):
    """A tiny run with checkpoints at steps 1 and 2 and no validation yet."""
    import torch

    from cliport.train.config import TrainConfig
    from cliport.train.trainer import train

    root = tmp_path_factory.mktemp("validation")
    make_synthetic_dataset(str(root), n_episodes=2)
    config = TrainConfig.build({
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": 2, "batch_size": 1,
        "data_dir": str(root), "run_dir": str(root / "run"), "device": "cpu", "num_workers": 0, "val_episodes": 0,
        "checkpoint_steps": [1], "checkpoint_every": 0,
        "agent_config": {"width": 0.125, "n_rotations": 4, "crop_size": 32}, "env": {"camera_scale": 0.5},
    })  # fmt: skip
    torch.manual_seed(0)
    train(config, progress=False)
    return str(root / "run")


def _copy_run(run_dir: str, to, steps: tuple[int, ...] = (1, 2)) -> str:
    """A copy of ``run_dir`` holding only the checkpoints of ``steps``."""
    import os
    import shutil

    shutil.copytree(run_dir, to)
    for step in {1, 2} - set(steps):
        os.remove(RunDir(str(to)).checkpoint(step))
    return str(to)


# Validated on block-insertion (at most 3 actions an episode, against place-red-in-green's 10): the
# validator does not care which task the agent was trained on.
VAL_TASK = "block-insertion"


@pytest.mark.e2e  # waits out a step timeout
def test_a_hung_simulator_hangs_neither_validation_nor_training(trained_run, tmp_path, monkeypatch):
    """Beside-mode validation whose simulator hangs in its episode: the worker is killed and replaced,
    finish() returns (training would end), and val.json is what an undisturbed validation writes."""
    import time

    import torch

    from cliport.evaluation.stepper import HANG_ENV
    from cliport.evaluation.validation import BackgroundValidator, validate_run

    cpu = torch.device("cpu")
    clean = validate_run(_copy_run(trained_run, tmp_path / "clean", (1,)), VAL_TASK, 1, 0.5, cpu, progress=False)
    run_dir = _copy_run(trained_run, tmp_path / "hung", (1,))
    monkeypatch.setenv(HANG_ENV, f"1:{tmp_path / 'hung-marker'}")  # val seed 1, in the grandchild
    validator = BackgroundValidator(run_dir, VAL_TASK, 1, 0.5, cpu, progress=False, workers=1, step_timeout=3.0)
    start = time.monotonic()
    validator.checkpoint_saved(1, RunDir(run_dir).checkpoint(1))
    results = validator.finish()
    assert (tmp_path / "hung-marker-1").exists()  # it did hang
    assert results == read_json(RunDir(run_dir).val) == clean and set(clean["checkpoints"]) == {"1"}
    assert clean["renderer"] == "tiny"
    assert time.monotonic() - start < 120


def test_validation_holds_one_agent_at_a_time(trained_run, tmp_path, monkeypatch):
    """Each checkpoint's agent is gone (by reference counting alone) before the next one is loaded."""
    import gc
    import weakref

    import numpy as np
    import torch

    from cliport.agents import PickPlaceAgent
    from cliport.evaluation import validation
    from cliport.evaluation.evaluate import summarise

    loaded: list[weakref.ref] = []
    real = PickPlaceAgent.from_pretrained

    def from_pretrained(*args, **kwargs):
        assert all(ref() is None for ref in loaded), "the previous checkpoint's agent is still alive"
        agent = real(*args, **kwargs)
        loaded.append(weakref.ref(agent))
        return agent

    def evaluate(agent, *args, **kwargs):  # the episodes do not matter here: one act() uses the agent
        agent.act({"color": np.zeros((64, 32, 3), np.uint8), "height": np.zeros((64, 32), np.float32)})
        return {**summarise(VAL_TASK, "val", [{"seed": 1, "total_reward": 0.0, "actions": 1}]), "renderer": "tiny"}

    monkeypatch.setattr(PickPlaceAgent, "from_pretrained", from_pretrained)
    monkeypatch.setattr(validation, "evaluate", evaluate)
    run_dir = _copy_run(trained_run, tmp_path / "run")
    gc.collect()
    gc.disable()
    try:
        validation.validate_run(run_dir, VAL_TASK, 1, 0.5, torch.device("cpu"), progress=False, workers=1)
    finally:
        gc.enable()
    assert len(loaded) == 2 and all(ref() is None for ref in loaded)
