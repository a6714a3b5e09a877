"""A start that can learn: nets dead under their first initial weights are drawn again before training."""

from __future__ import annotations

import csv

import pytest
import torch

from cliport.agents import make_agent
from cliport.models.preprocess import raw_input
from cliport.train import live_start
from cliport.train.config import TrainConfig
from cliport.train.live_start import DeadStartError, dead_nets, ensure_live
from cliport.train.trainer import train


def _inputs(agent, seed: int = 0) -> dict:
    """One (1, 128, 64) scene with a raised block, its pick pixel and a sentence."""
    g = torch.Generator().manual_seed(seed)
    color = torch.randint(0, 255, (1, 128, 64, 3), dtype=torch.uint8, generator=g)
    height = torch.zeros(1, 128, 64)
    height[0, 60:66, 30:36] = 0.05
    return {
        "color": color,
        "height": height,
        "pick_pix": torch.tensor([[63, 33]]),
        "sentence": agent.sentence_features(["put the red block in the green bowl"]),
    }


def _kill_key_semantic(agent) -> None:
    """Make the place key net's semantic stream negative at every pixel, as some initial draws leave it."""
    out = agent.place.key_net.semantic.out
    with torch.no_grad():
        out.weight.zero_()
        out.bias.fill_(-1.0)


@pytest.fixture(scope="module")
def agent_factory(tiny_config):
    def make():
        torch.manual_seed(2)  # a live draw (0 and 1 draw a dead key semantic stream)
        return make_agent(
            "two_stream", tiny_config("two_stream", crop_size=64, n_rotations=1, semantic_encoder="RN50-quickgelu")
        ).train()

    return make


def test_a_dead_fusion_stream_is_found_and_drawn_again_from_the_seed(agent_factory) -> None:
    agent = agent_factory()
    inputs = _inputs(agent)
    assert dead_nets(agent, inputs) == {}
    _kill_key_semantic(agent)
    assert dead_nets(agent, inputs) == {
        "place": "its key_net.fuse's semantic stream is negative everywhere, so the ReLU zeroes it"
    }
    pick = {k: v.clone() for k, v in agent.pick.state_dict().items()}
    frozen = {n: p.clone() for n, p in agent.named_parameters() if not p.requires_grad}
    assert frozen, "the agent has a frozen encoder"
    buffers = {n: b.clone() for n, b in agent.named_buffers()}
    rng = torch.get_rng_state()

    reason = "its key_net.fuse's semantic stream is negative everywhere, so the ReLU zeroes it"
    assert ensure_live(agent, inputs, seed=5) == {"place": {"draws": 2, "reason": reason}}
    assert dead_nets(agent, inputs) == {}
    assert torch.equal(torch.get_rng_state(), rng), "a redraw leaves the global random state alone"
    for name, value in agent.pick.state_dict().items():
        assert torch.equal(value, pick[name]), name
    for name, param in agent.named_parameters():
        if not param.requires_grad:
            assert torch.equal(param, frozen[name]), name
    for name, buffer in agent.named_buffers():
        if not name.startswith("place."):
            assert torch.equal(buffer, buffers[name]), f"the check's forward changed {name}"

    again = agent_factory()
    _kill_key_semantic(again)
    ensure_live(again, inputs, seed=5)
    for (name, a), b in zip(agent.place.state_dict().items(), again.place.state_dict().values(), strict=True):
        assert torch.equal(a, b), f"the same seed draws the same {name}"


def test_a_constant_place_map_is_found_and_a_net_that_stays_dead_is_one_error(agent_factory, monkeypatch) -> None:
    agent = agent_factory()
    inputs = _inputs(agent)
    with torch.no_grad():
        agent.place.key_net.fuse.weight.zero_()  # every place logit 0: the map a dead fusion gives
    x = raw_input(inputs["color"], inputs["height"])
    with torch.no_grad():
        assert torch.all(agent.place(x, inputs["pick_pix"], inputs["sentence"]) == 0)
    assert dead_nets(agent, inputs) == {"place": "its output map is constant"}

    monkeypatch.setattr(live_start, "redraw", lambda net, seed: None)
    monkeypatch.setattr(live_start, "MAX_DRAWS", 3)
    with pytest.raises(DeadStartError, match=r"^the place net cannot learn from this input under any of 3 "):
        ensure_live(agent, inputs, seed=0)


def test_training_draws_a_dead_start_again_and_records_it(tmp_path, make_synthetic_dataset, monkeypatch) -> None:
    """A run whose first place net is dead draws it again, records the draw in its summary and learns."""
    from cliport import agents

    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    real_make_agent = agents.make_agent

    def dead_start(*args, **kwargs):
        agent = real_make_agent(*args, **kwargs)
        with torch.no_grad():
            agent.place.key_net.fuse.weight.zero_()
        return agent

    monkeypatch.setattr(agents, "make_agent", dead_start)
    summary = train(TrainConfig.build({
        "agent": "two_stream", "task": "place-red-in-green", "n_demos": 2, "n_steps": 4, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / "dead"), "device": "cpu", "num_workers": 0,
        "val_episodes": 0, "checkpoint_steps": [4], "checkpoint_every": 0, "log_every": 2,
        "agent_config": {"width": 0.0625, "crop_size": 64, "n_rotations": 1, "clip_weights": "random"},
    }), progress=False)  # fmt: skip
    assert summary["init_draws"] == {"place": {"draws": 2, "reason": "its output map is constant"}}
    with open(tmp_path / "dead" / "metrics.csv") as f:
        place = [float(row["place_loss"]) for row in csv.DictReader(f)]
    assert len(place) == 2 and place[0] != place[1], "the redrawn place net learns"
