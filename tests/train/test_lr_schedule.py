"""The learning-rate cooldown: its shape, the trainer's use of it over a resume and a time budget, the switch."""

from __future__ import annotations

import pytest
import torch

from cliport.errors import ConfigError
from cliport.train import graphed_step
from cliport.train.config import TrainConfig
from cliport.train.lr_schedule import LrCooldown, cooldown_factor
from cliport.train.trainer import train
from cliport.utils.files import load_torch
from cliport.utils.run_dir import RunDir


def test_the_factor_is_constant_then_falls_linearly_to_zero() -> None:
    assert [cooldown_factor(p, 0.0) for p in (0.0, 0.5, 1.0)] == [1.0, 1.0, 1.0]
    assert [cooldown_factor(p, 0.25) for p in (0.0, 0.75, 0.875, 1.0, 1.2)] == [1.0, 1.0, 0.5, 0.0, 0.0]
    assert cooldown_factor(0.0, 1.0) == 1.0 and cooldown_factor(0.5, 1.0) == 0.5


def test_every_parameter_group_is_scaled_from_its_own_rate() -> None:
    a, b = torch.nn.Parameter(torch.zeros(1)), torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.Adam([{"params": [a], "lr": 1e-3}, {"params": [b], "lr": 4e-3}])
    cooldown = LrCooldown(optimizer, 0.5)
    assert cooldown.apply(0.75) == 0.5
    assert [group["lr"] for group in optimizer.param_groups] == [5e-4, 2e-3]
    cooldown.apply(0.0)
    assert [group["lr"] for group in optimizer.param_groups] == [1e-3, 4e-3]


def _config(tmp_path, tiny_config, **overrides) -> TrainConfig:
    base = {
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": 8, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / "run"), "device": "cpu", "num_workers": 0,
        "val_episodes": 0, "checkpoint_steps": [8], "checkpoint_every": 0, "save_last_every": 100,
        "agent_config": tiny_config("transporter_only", n_rotations=4, lr=1e-3), "lr_cooldown": 0.75,
    }  # fmt: skip
    return TrainConfig.build({**base, **overrides})


def _last_lr(tmp_path) -> float:
    payload = load_torch(RunDir(str(tmp_path / "run")).checkpoint("last"))
    return payload["trainer"]["optimizer"]["param_groups"][0]["lr"]


def test_a_resumed_run_cools_down_from_the_configured_rate(tmp_path, make_synthetic_dataset, tiny_config) -> None:
    """Interrupted after step 4 (its rate already cooled and saved), resumed: the last step's rate is the
    configured one times the factor at step 7 of 8, not the saved rate cooled again."""
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    config = _config(tmp_path, tiny_config)

    def interrupt(step: int) -> None:
        if step == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(config, progress=False, step_hook=interrupt)
    assert _last_lr(tmp_path) == pytest.approx(1e-3 * cooldown_factor(3 / 8, 0.75))
    summary = train(config, resume=True, progress=False)
    assert summary["steps"] == 8
    assert _last_lr(tmp_path) == pytest.approx(1e-3 * cooldown_factor(7 / 8, 0.75))


def test_a_time_budget_cools_down_by_the_time_spent(tmp_path, make_synthetic_dataset, tiny_config) -> None:
    """A run that stops on its time budget, long before n_steps, ends with its rate near zero."""
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    summary = train(_config(tmp_path, tiny_config, n_steps=100_000, time_budget_s=3.0), progress=False)
    assert summary["stopped_by"] == "time_budget"
    # By its steps the run is at its very start (rate 1e-3); by its time, the last step began in the budget's last
    # 30 % (a tiny step takes well under 0.9 s even on a loaded CPU), at a rate under 0.4 of the configured one.
    assert 0 <= _last_lr(tmp_path) < 1e-3 * 0.4


def test_a_cooldown_trains_eagerly_where_steps_would_be_captured(
    tmp_path, make_synthetic_dataset, tiny_config, monkeypatch, capsys
) -> None:
    monkeypatch.setattr(graphed_step, "CAPTURE_DEVICES", {"cuda", "cpu"})
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    summary = train(_config(tmp_path, tiny_config), progress=False)
    assert summary["step_kinds"] == {"graph_replays": 0, "eager": 8}
    err = capsys.readouterr().err
    assert "cooldown trains eagerly" in err and "train transporter_only" not in err  # progress=False: no bar


def test_the_cooldown_is_a_fraction_and_a_flag(tmp_path) -> None:
    from cliport.cli.train import _parser, config_from_args

    with pytest.raises(ConfigError, match="lr_cooldown is a fraction of the run, from 0 to 1, got 1.5"):
        TrainConfig.build({"agent": "transporter_only", "task": "place-red-in-green", "lr_cooldown": 1.5})
    parser, dests = _parser()
    assert config_from_args(parser.parse_args(["--task", "place-red-in-green"]), dests).lr_cooldown == 0.0
    args = parser.parse_args(["--task", "place-red-in-green", "--lr-cooldown", "0.25"])
    assert config_from_args(args, dests).lr_cooldown == 0.25
