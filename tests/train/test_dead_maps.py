import functools
import math

import pytest

from cliport.train.config import TrainConfig
from cliport.train.dead_maps import DeadMapError, DeadMapWatch
from cliport.train.trainer import train


def test_a_repeated_loss_stops_after_patience_and_names_the_net() -> None:
    watch = DeadMapWatch(patience=3)
    for step, place in enumerate([9.1, 8.7, 10.84349, 10.84349, 10.84349], start=1):
        watch.observe(step, {"pick_loss": 10.0 - step / 10, "place_loss": place})
    with pytest.raises(DeadMapError, match=r"step 6: the place net's output has been constant since step 3"):
        watch.observe(6, {"pick_loss": 9.3, "place_loss": 10.84349})


def test_a_loss_that_moves_again_resets_the_count() -> None:
    watch = DeadMapWatch(patience=3)
    losses = [5.0, 5.0, 5.0, 5.1, 5.1, 5.1, 4.0, 4.0, 4.0]  # never 3 steps past the first repeat
    for step, value in enumerate(losses, start=1):
        watch.observe(step, {"pick_loss": value, "place_loss": 7.0 + step})


def test_training_stops_when_the_place_map_goes_constant(
    tmp_path, make_synthetic_dataset, monkeypatch, tiny_config
) -> None:
    """A key net that outputs zeros makes every place logit zero, as a dead FusionConv does: the loss is
    ln(cells) at every step and the run stops with the error instead of training on."""
    from cliport import agents

    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    real_make_agent = agents.make_agent

    def dead_key(*args, **kwargs):
        agent = real_make_agent(*args, **kwargs)
        forward = agent.place.key_net.forward
        agent.place.key_net.forward = lambda *a, **k: forward(*a, **k) * 0.0
        return agent

    monkeypatch.setattr(agents, "make_agent", dead_key)
    monkeypatch.setattr("cliport.train.trainer.DeadMapWatch", functools.partial(DeadMapWatch, patience=3))
    overrides = {
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": 20, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / "run"), "device": "cpu", "num_workers": 0,
        "val_episodes": 0, "checkpoint_steps": [20], "checkpoint_every": 0,
        "agent_config": tiny_config("transporter_only", n_rotations=4),
    }  # fmt: skip
    with pytest.raises(DeadMapError) as caught:
        train(TrainConfig.build(overrides), progress=False)
    message = str(caught.value)
    assert message.startswith("step 4: the place net's output has been constant since step 1")
    cells = float(message.split("its loss is ")[1].split(",")[0])
    assert math.isclose(cells, math.log(4 * 320 * 160), abs_tol=1e-4)
