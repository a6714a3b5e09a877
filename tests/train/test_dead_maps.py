import functools
import math
import os

import pytest
import torch

from cliport.train.config import TrainConfig
from cliport.train.dead_maps import DeadMapError, DeadMapWatch
from cliport.train.trainer import train


def _terms(pick: float, place: float) -> torch.Tensor:
    """One step's (3,) float32 terms, as a training step leaves them on the device."""
    return torch.tensor([pick + place, pick, place], dtype=torch.float32)


def test_a_repeated_loss_stops_after_patience_and_names_the_net() -> None:
    watch = DeadMapWatch(patience=3)
    for step, place in enumerate([9.1, 8.7, 10.84349, 10.84349, 10.84349], start=1):
        watch.observe(_terms(10.0 - step / 10, place))
        watch.check()
    watch.observe(_terms(9.3, 10.84349))
    with pytest.raises(DeadMapError, match=r"step 6: the place net's output has been constant since step 3"):
        watch.check()


def test_a_dead_map_is_reported_at_the_step_it_was_found_when_read_later() -> None:
    """The trainer reads the watch every log_every steps: the message names the step the map was found dead
    at, counted from the resumed run's start, whatever the later steps did."""
    watch = DeadMapWatch(patience=3, start_step=100)
    for step, pick in enumerate([5.0, 5.0, 5.0, 5.0, 4.0, 3.0], start=1):
        watch.observe(_terms(pick, 7.0 + step))
    with pytest.raises(DeadMapError, match=r"step 104: the pick net's output has been constant since step 101"):
        watch.check()


def test_a_loss_that_moves_again_resets_the_count() -> None:
    watch = DeadMapWatch(patience=3)
    losses = [5.0, 5.0, 5.0, 5.1, 5.1, 5.1, 4.0, 4.0, 4.0]  # never 3 steps past the first repeat
    for step, value in enumerate(losses, start=1):
        watch.observe(_terms(value, 7.0 + step))
    watch.check()


def test_float32_neighbours_count_as_the_same_loss_and_1e_5_apart_do_not() -> None:
    """The tolerance is 1e-6 on float32 losses near ln(cells) ~ 10.8, where neighbouring float32 values are
    ~1e-6 apart: one ulp is the same loss, ten are not."""
    value = torch.tensor(10.84349, dtype=torch.float32)
    ulp = torch.nextafter(value, torch.tensor(11.0)) - value
    watch = DeadMapWatch(patience=2)
    for k in (0, 1, 0):
        watch.observe(_terms(1.0 + k, float(value + k * ulp)))
    with pytest.raises(DeadMapError, match="place net"):
        watch.check()
    watch = DeadMapWatch(patience=2)
    for k in (0, 10, 0):
        watch.observe(_terms(1.0 + k, float(value + k * ulp)))
    watch.check()


def test_training_stops_when_the_place_map_goes_constant(
    tmp_path, make_synthetic_dataset, monkeypatch, tiny_config
) -> None:
    """A key net that outputs zeros makes every place logit zero, as a dead FusionConv does: the loss is
    ln(cells) at every step and the run stops with the error instead of training on: at the first metrics row
    after the map was found dead (step 6, log_every 3), naming the step it was found at (4)."""
    from cliport import agents

    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    real_make_agent = agents.make_agent

    def dead_key(*args, **kwargs):
        agent = real_make_agent(*args, **kwargs)
        forward = agent.place.key_net.forward
        # Dead from the first training step on: the start check (live_start, without gradients) sees a live net.
        agent.place.key_net.forward = lambda *a, **k: forward(*a, **k) * float(not torch.is_grad_enabled())
        return agent

    monkeypatch.setattr(agents, "make_agent", dead_key)
    monkeypatch.setattr("cliport.train.step_loop.DeadMapWatch", functools.partial(DeadMapWatch, patience=3))
    overrides = {
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": 20, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / "run"), "device": "cpu", "num_workers": 0,
        "val_episodes": 0, "checkpoint_steps": [20], "checkpoint_every": 0, "log_every": 3,
        "agent_config": tiny_config("transporter_only", n_rotations=4),
    }  # fmt: skip
    with pytest.raises(DeadMapError) as caught:
        train(TrainConfig.build(overrides), progress=False)
    message = str(caught.value)
    assert message.startswith("step 4: the place net's output has been constant since step 1")
    cells = float(message.split("its loss is ")[1].split(",")[0])
    assert math.isclose(cells, math.log(4 * 320 * 160), abs_tol=1e-4)
    with open(tmp_path / "run" / "metrics.csv") as f:
        assert [row.split(",")[0] for row in f.read().split()[1:]] == ["3"]  # stopped at the row of step 6
    assert not os.path.exists(tmp_path / "run" / "checkpoints" / "last.pt")
