"""CUDA speed settings: graphed acting equals eager acting; channels_last, bf16 CLIP and fused Adam are on.

All GPU-only (skipped without CUDA); the CPU side of these settings is tested in test_act_batch.py.
"""

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent

H, W = 320, 160
CONFIGS = {"transporter_only": {"width": 0.125}, "two_stream": {"width": 0.125, "clip_weights": "random"}}
INSTRUCTIONS = ["put the red block in the green bowl", "pack the blue block", "stack the blocks"]

pytestmark = pytest.mark.gpu


def _observations(n: int, seed: int) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [
        {
            "color": rng.integers(0, 255, (H, W, 3), dtype=np.uint8),
            "height": rng.uniform(0, 0.05, (H, W)).astype(np.float32),
        }
        for _ in range(n)
    ]


def _agent(name: str) -> PickPlaceAgent:
    torch.manual_seed(0)
    return make_agent(name, CONFIGS[name]).to("cuda")


def _assert_same(got: list[dict], expected: list[dict]) -> None:
    for a, b in zip(got, expected, strict=True):
        assert a["pick_pix"] == b["pick_pix"] and a["place_pix"] == b["place_pix"]
        assert a["place_rot"] == b["place_rot"]
        np.testing.assert_allclose(a["pick_heatmap"], b["pick_heatmap"], rtol=0, atol=1e-5)
        np.testing.assert_allclose(a["place_heatmap"], b["place_heatmap"], rtol=0, atol=1e-5)


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
def test_graphed_act_equals_eager(name: str) -> None:
    agent = _agent(name)
    assert agent.pick.input_memory_format == torch.channels_last
    for batch_size, seed in [(2, 0), (2, 1), (1, 2), (3, 3)]:
        observations = _observations(batch_size, seed)
        instructions = INSTRUCTIONS[:batch_size] if name == "two_stream" else [None] * batch_size
        agent.set_act_graphs(False)
        eager = agent.act_batch(observations, instructions)
        agent.set_act_graphs(True)
        graphed = agent.act_batch(observations, instructions)  # captures (batch sizes 2, 1, 3) or replays
        _assert_same(graphed, eager)
        _assert_same(agent.act_batch(observations, instructions), eager)  # replays
    assert len(agent._pick_graphs) == 3 and len(agent._place_graphs) == 3


def test_settings_follow_the_device() -> None:
    agent = _agent("two_stream")
    weights = [p for p in agent.pick.net.spatial.parameters() if p.dim() == 4]
    assert all(p.is_contiguous(memory_format=torch.channels_last) for p in weights)
    assert next(agent.encoder.model.visual.parameters()).dtype == torch.bfloat16
    assert next(agent.encoder.model.transformer.parameters()).dtype == torch.float32
    optimizer = agent.make_optimizer()
    assert optimizer.defaults["fused"]
    batch = {
        "color": torch.randint(0, 255, (2, H, W, 3), dtype=torch.uint8).pin_memory(),
        "height": (torch.rand(2, H, W) * 0.05).pin_memory(),
        "pick_pix": torch.tensor([[10, 20], [100, 50]]),
        "place_pix": torch.tensor([[200, 30], [50, 140]]),
        "place_rot": torch.tensor([3, 30]),
        "lang": INSTRUCTIONS[:2],
    }
    info = agent.train_step(batch, optimizer)
    assert np.isfinite(info["loss"])
    agent.to("cpu")
    assert agent.pick.input_memory_format == torch.contiguous_format
    assert next(agent.encoder.model.visual.parameters()).dtype == torch.float32
    assert all(p.is_contiguous() for p in agent.parameters())


def test_switches_turn_each_setting_off() -> None:
    torch.manual_seed(0)
    agent = make_agent("two_stream", CONFIGS["two_stream"])
    agent.optimize_for_device(channels_last=False, bf16_clip=False, fused_adam=False, act_graphs=False).to("cuda")
    assert agent.pick.input_memory_format == torch.contiguous_format
    assert next(agent.encoder.model.visual.parameters()).dtype == torch.float32
    assert not agent.make_optimizer().defaults["fused"]
    agent.act(_observations(1, 0)[0], INSTRUCTIONS[0])
    assert len(agent._pick_graphs) == 0
