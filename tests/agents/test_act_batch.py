"""Batched acting and batched losses agree with batch 1; a checkpoint saved before issue 15's changes acts
exactly as it did then (fixtures written by tests/fixtures/make_act_fixtures.py at fcea851)."""

import lzma
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, load_agent, make_agent
from cliport.models.blocks import set_upsample_mode

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
H, W = 64, 32
TINY = {"width": 0.125, "crop_size": 32, "n_rotations": 8}
CONFIGS = {"transporter_only": TINY, "two_stream": {**TINY, "clip_weights": "random"}}
INSTRUCTIONS = ["put the red block in the green bowl", "pack the blue block", "put the red block in the green bowl"]


def _load_fixture_agent(name: str, tmp_path: Path) -> PickPlaceAgent:
    path = FIXTURES / f"{name}_w0125.pt"
    if not path.exists():
        path = tmp_path / f"{name}.pt"
        with lzma.open(FIXTURES / f"{name}_w0125.pt.xz", "rb") as src, open(path, "wb") as dst:
            shutil.copyfileobj(src, dst)
    return load_agent(path)


@pytest.fixture
def upsample_mode() -> Iterator[Callable[[str], None]]:
    yield set_upsample_mode
    set_upsample_mode("auto")


# "stencil": the up-sampling used on CUDA, here on the CPU (the two-stream nets' equality under it is
# tested in tests/models/test_upsample.py).
@pytest.mark.parametrize(
    ("name", "mode"), [("transporter_only", "auto"), ("transporter_only", "stencil"), ("two_stream", "auto")]
)
def test_pre_change_checkpoint_acts_identically(
    name: str, mode: str, tmp_path: Path, upsample_mode: Callable[[str], None]
) -> None:
    upsample_mode(mode)
    agent = _load_fixture_agent(name, tmp_path)
    saved_obs = np.load(FIXTURES / "act_obs.npz")
    expected = np.load(FIXTURES / f"act_{name}.npz")
    obs = {"color": saved_obs["color"], "height": saved_obs["height"]}
    instruction = str(saved_obs["instruction"]) if name == "two_stream" else None
    out = agent.act(obs, instruction)
    assert out["pick_pix"] == tuple(expected["pick_pix"].tolist())
    assert out["place_pix"] == tuple(expected["place_pix"].tolist())
    assert out["place_rot"] == pytest.approx(float(expected["place_rot"]), abs=1e-12)
    # The stencil rounds differently from F.interpolate (1 ulp); the trained place logits are large, and
    # a softmax peak of 0.42 then moves by up to ~6e-4 relative.
    rtol = 2e-3 if mode == "stencil" else 0.0
    np.testing.assert_allclose(out["pick_heatmap"], expected["pick_heatmap"], rtol=rtol, atol=1e-5)
    np.testing.assert_allclose(out["place_heatmap"], expected["place_heatmap"], rtol=rtol, atol=1e-5)


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


def _batch(observations: list[dict[str, np.ndarray]], seed: int) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    n = len(observations)
    return {
        "color": torch.from_numpy(np.stack([o["color"] for o in observations])),
        "height": torch.from_numpy(np.stack([o["height"] for o in observations])),
        "pick_pix": torch.from_numpy(rng.integers(0, [H, W], (n, 2))),
        "place_pix": torch.from_numpy(rng.integers(0, [H, W], (n, 2))),
        "place_rot": torch.from_numpy(rng.integers(0, TINY["n_rotations"], n)),
        "lang": INSTRUCTIONS[:n],
    }


def _trained_agent(name: str) -> PickPlaceAgent:
    """A tiny agent trained a few steps, so that its heatmaps have clear maxima (not float-rounding ties)."""
    torch.manual_seed(0)
    agent = make_agent(name, CONFIGS[name])
    optimizer = torch.optim.Adam(agent.trainable_parameters(), lr=3e-3)
    batch = _batch(_observations(3), seed=1)
    for _ in range(8):
        agent.train_step(batch, optimizer)
    return agent


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
def test_act_batch_equals_act(name: str) -> None:
    agent = _trained_agent(name)
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


def test_two_stream_act_batch_needs_every_instruction() -> None:
    agent = make_agent("two_stream", CONFIGS["two_stream"])
    with pytest.raises(ValueError, match="instruction"):
        agent.act_batch(_observations(2), [INSTRUCTIONS[0], None])


@pytest.mark.parametrize("name", ["transporter_only", "two_stream"])
def test_batch_loss_is_mean_of_single_losses(name: str) -> None:
    torch.manual_seed(0)
    agent = make_agent(name, CONFIGS[name])
    batch = _batch(_observations(3), seed=2)
    with torch.no_grad():
        loss, info = agent.compute_loss(batch)
        singles = []
        for i in range(3):
            one = {k: v[i : i + 1] for k, v in batch.items()}
            singles.append(agent.compute_loss(one)[1])
    for key in ("loss", "pick_loss", "place_loss"):
        assert info[key] == pytest.approx(np.mean([s[key] for s in singles]), rel=1e-5)
    assert loss.item() == pytest.approx(info["loss"])


def test_device_options_stay_off_on_cpu() -> None:
    agent = make_agent("transporter_only", TINY).optimize_for_device()
    assert all(agent.device_options.values())
    assert agent.pick.input_memory_format == torch.contiguous_format
    assert all(p.is_contiguous() for p in agent.parameters())
    optimizer = agent.make_optimizer()
    assert optimizer.defaults["foreach"] and not optimizer.defaults["fused"]
    agent.set_act_graphs(False)
    assert not agent.device_options["act_graphs"]
    agent.act(_observations(1)[0])
    assert len(agent._pick_graphs) == 0 and len(agent._place_graphs) == 0
