"""Batched acting and batched losses agree with batch 1: batch-mates never change each other's results."""

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.agents.loss import optimizer_step

H, W = 64, 32
INSTRUCTIONS = ["put the red block in the green bowl", "pack the blue block", "put the red block in the green bowl"]


def _observations(n: int) -> list[dict[str, np.ndarray]]:
    """n different scenes, each with a few raised coloured boxes."""
    rng = np.random.default_rng(7)
    scenes = []
    for _ in range(n):
        color = rng.integers(0, 60, (H, W, 3), dtype=np.uint8)
        height = rng.uniform(0, 0.002, (H, W)).astype(np.float32)
        for _ in range(3):
            u, v = int(rng.integers(6, H - 6)), int(rng.integers(6, W - 6))
            color[u - 3 : u + 3, v - 3 : v + 3] = rng.integers(80, 255, 3, dtype=np.uint8)
            height[u - 3 : u + 3, v - 3 : v + 3] = rng.uniform(0.01, 0.05)
        scenes.append({"color": color, "height": height})
    return scenes


def _batch(observations: list[dict[str, np.ndarray]], seed: int, n_rotations: int) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    n = len(observations)
    return {
        "color": torch.from_numpy(np.stack([o["color"] for o in observations])),
        "height": torch.from_numpy(np.stack([o["height"] for o in observations])),
        "pick_pix": torch.from_numpy(rng.integers(0, [H, W], (n, 2))),
        "place_pix": torch.from_numpy(rng.integers(0, [H, W], (n, 2))),
        "place_rot": torch.from_numpy(rng.integers(0, n_rotations, n)),
        "lang": INSTRUCTIONS[:n],
    }


def _trained_agent(name: str, config: dict[str, object]) -> PickPlaceAgent:
    """A tiny agent trained a few steps, so that its heatmaps have clear maxima (not float-rounding ties)."""
    torch.manual_seed(0)
    agent = make_agent(name, config)
    optimizer = torch.optim.Adam(agent.trainable_parameters(), lr=3e-3)
    batch = _batch(_observations(3), seed=1, n_rotations=agent.config.n_rotations)
    agent.train()
    for _ in range(8):
        optimizer_step(agent.compute_loss, batch, optimizer)
    return agent


@pytest.mark.parametrize("name", ["transporter_only", pytest.param("two_stream", marks=pytest.mark.e2e)])
def test_act_batch_equals_act(name: str, tiny_config) -> None:
    agent = _trained_agent(name, tiny_config(name))
    observations = _observations(3)
    instructions = INSTRUCTIONS if name == "two_stream" else [None] * 3
    batched = agent.act_batch(observations, instructions)
    assert len(batched) == 3
    for obs, instruction, got in zip(observations, instructions, batched, strict=True):
        single = agent.act(obs, instruction)
        assert set(got) == set(single)
        assert got["pick_pix"] == single["pick_pix"]
        assert got["place_pix"] == single["place_pix"]
        assert got["place_rot"] == single["place_rot"]
        assert got["pose0"] == single["pose0"] and got["pose1"] == single["pose1"]
        np.testing.assert_allclose(got["pick_heatmap"], single["pick_heatmap"], rtol=0, atol=1e-5)
        np.testing.assert_allclose(got["place_heatmap"], single["place_heatmap"], rtol=0, atol=1e-5)
    assert agent.act_batch([], []) == []
    with pytest.raises(ValueError, match="instructions"):
        agent.act_batch(observations, instructions[:2])


def test_two_stream_act_batch_needs_every_instruction(tiny_config) -> None:
    agent = make_agent("two_stream", tiny_config("two_stream"))
    with pytest.raises(ValueError, match="instruction"):
        agent.act_batch(_observations(2), [INSTRUCTIONS[0], None])


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
def test_batch_loss_is_mean_of_single_losses(name: str, tiny_config) -> None:
    torch.manual_seed(0)
    agent = make_agent(name, tiny_config(name))
    batch = _batch(_observations(3), seed=2, n_rotations=agent.config.n_rotations)
    with torch.no_grad():
        loss, info = agent.compute_loss(batch)
        singles = []
        for i in range(3):
            one = {k: v[i : i + 1] for k, v in batch.items()}
            singles.append(agent.compute_loss(one)[1])
    for key in ("loss", "pick_loss", "place_loss"):
        assert info[key] == pytest.approx(np.mean([s[key] for s in singles]), rel=1e-5)
    assert loss.item() == pytest.approx(info["loss"])


def test_device_options_but_fused_adam_stay_off_on_cpu(tiny_config) -> None:
    agent = make_agent("transporter_only", tiny_config("transporter_only")).optimize_for_device()
    assert all(agent.device_options.values())
    assert agent.pick.input_memory_format == torch.contiguous_format
    assert all(p.is_contiguous() for p in agent.parameters())
    optimizer = agent.make_optimizer()
    assert optimizer.defaults["fused"] and not optimizer.defaults["foreach"]
    agent.optimize_for_device(fused_adam=False)
    optimizer = agent.make_optimizer()
    assert optimizer.defaults["foreach"] and not optimizer.defaults["fused"]
    agent.set_act_graphs(False)
    assert not agent.device_options["act_graphs"]
    agent.act(_observations(1)[0])
    assert len(agent._pick_graphs) == 0 and len(agent._place_graphs) == 0
