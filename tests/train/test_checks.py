"""Training to a time budget, and checks of the training agent that keep the best step's checkpoint."""

from __future__ import annotations

import os

import pytest
import torch

from cliport.train.config import TrainConfig
from cliport.train.trainer import train
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory, make_synthetic_dataset) -> str:
    root = tmp_path_factory.mktemp("checks")
    make_synthetic_dataset(str(root), n_episodes=2)
    return str(root)


def _config(data_dir: str, run_dir, **overrides: object) -> TrainConfig:
    return TrainConfig.build({
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "batch_size": 1,
        "data_dir": data_dir, "run_dir": str(run_dir), "device": "cpu", "num_workers": 0, "val_episodes": 0,
        "checkpoint_every": 0, "agent_config": {"width": 0.125, "n_rotations": 4, "crop_size": 32},
        "env": {"camera_scale": 0.5}, **overrides,
    })  # fmt: skip


class StepScore:
    """Scores the agent by a table of steps (what a held-out check would find), recording what it saw."""

    def __init__(self, scores: dict[int, float], every: int) -> None:
        self.scores, self.every, self.seen = scores, every, []

    def due(self, step: int) -> bool:
        return step % self.every == 0

    def check(self, step: int, agent) -> dict:
        self.seen.append((step, agent.training))
        return {"score": self.scores[step]}

    def describe(self) -> dict:
        return {"every": self.every}


def test_the_best_checked_step_keeps_its_checkpoint_and_is_the_runs_best(data_dir, tmp_path) -> None:
    check = StepScore({2: 0.2, 4: 0.5, 6: 0.4, 8: 0.3}, every=2)
    torch.manual_seed(0)
    summary = train(_config(data_dir, tmp_path / "run", n_steps=8, checkpoint_steps=[8]), progress=False, check=check)
    run = RunDir(str(tmp_path / "run"))
    assert [step for step, _ in check.seen] == [2, 4, 6, 8]
    curve = read_json(run.held_out)
    assert curve["best_step"] == 4 and curve["best_score"] == 0.5 and curve["check"] == {"every": 2}
    assert [row["step"] for row in curve["curve"]] == [2, 4, 6, 8]
    assert run.best_step() == 4 and summary["held_out"] == {"best_step": 4, "best_score": 0.5}
    # step 2 was the best until step 4 replaced it; 6 never was; 8 is the schedule's (the last step)
    assert os.path.exists(run.checkpoint(4)) and os.path.exists(run.checkpoint(8))
    assert not os.path.exists(run.checkpoint(2)) and not os.path.exists(run.checkpoint(6))


def test_a_time_budget_stops_training_checkpoints_the_step_and_holds_over_a_resume(data_dir, tmp_path) -> None:
    config = _config(data_dir, tmp_path / "run", n_steps=100_000, checkpoint_steps=[100_000], time_budget_s=3.0)
    torch.manual_seed(0)
    first = train(config, progress=False)
    assert first["stopped_by"] == "time_budget" and 0 < first["steps"] < 100_000
    assert first["trained_s"] >= 3.0
    run = RunDir(str(tmp_path / "run"))
    assert run.checkpoint_steps() == [first["steps"]]  # checkpointed as the schedule's last step would be
    again = train(config, resume=True, progress=False)  # the budget is spent: nothing more is trained
    assert again["steps"] == first["steps"] and again["stopped_by"] == "time_budget"


def test_checks_need_a_single_process_and_a_budget_cannot_be_negative(data_dir, tmp_path) -> None:
    with pytest.raises(Exception, match="time_budget_s"):
        _config(data_dir, tmp_path / "run", n_steps=2, time_budget_s=-1)
