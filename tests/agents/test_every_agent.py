"""Every registered agent, with random pretrained parts: builds, trains, acts, round-trips a checkpoint,
and keeps its frozen encoder frozen. New agents are covered by registering them."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from cliport.agents import PickPlaceAgent, agent_class, agent_names, make_agent
from cliport.agents.loss import optimizer_step

H, W = 64, 32
INSTRUCTION = "put the red block in the green bowl"


def _scene(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "color": rng.integers(0, 255, (H, W, 3), dtype=np.uint8),
        "height": rng.uniform(0, 0.05, (H, W)).astype(np.float32),
    }


def _batch() -> dict[str, object]:
    scenes = [_scene(0), _scene(1)]
    return {
        "color": torch.from_numpy(np.stack([s["color"] for s in scenes])),
        "height": torch.from_numpy(np.stack([s["height"] for s in scenes])),
        "pick_pix": torch.tensor([[10, 7], [40, 20]]),
        "place_pix": torch.tensor([[45, 23], [12, 5]]),
        "place_rot": torch.tensor([3, 6]),
        "lang": [INSTRUCTION, "put the blue block in the yellow bowl"],
    }


@pytest.fixture(scope="module", params=agent_names())
def trained(request: pytest.FixtureRequest, tiny_config) -> tuple[PickPlaceAgent, dict[str, torch.Tensor], list[float]]:
    """An agent after two training steps, with a copy of its frozen state from before them."""
    torch.manual_seed(0)
    agent = make_agent(request.param, tiny_config(request.param))
    frozen_before = {} if agent.encoder is None else {k: v.clone() for k, v in agent.encoder.state_dict().items()}
    optimizer = agent.make_optimizer()
    agent.train()
    losses = [optimizer_step(agent.compute_loss, _batch(), optimizer)["loss"] for _ in range(2)]
    return agent, frozen_before, losses


def test_trains_two_steps(trained) -> None:
    agent, _, losses = trained
    assert all(math.isfinite(v) for v in losses)
    assert losses[1] < losses[0]


def test_frozen_encoder_stays_frozen(trained) -> None:
    agent, frozen_before, _ = trained
    if agent.encoder is None:
        assert not agent_class(agent.name).weight_sources
        return
    encoder = agent.encoder
    assert not any(p.requires_grad for p in encoder.parameters())
    assert not any(p.grad is not None for p in encoder.parameters())
    agent.train()
    assert not any(m.training for m in encoder.modules())  # batch norms keep their statistics
    after = encoder.state_dict()
    assert frozen_before.keys() == after.keys()
    assert all(torch.equal(frozen_before[k], after[k]) for k in after)
    trainable = {id(p) for p in agent.trainable_parameters()}
    assert not any(id(p) in trainable for p in encoder.parameters())


def test_acts_and_reloads_identically(trained, tmp_path: Path) -> None:
    agent, _, _ = trained
    instruction = INSTRUCTION if agent.uses_language else None
    out = agent.act(_scene(2), instruction)
    assert out["pick_heatmap"].shape == (H, W) and out["place_heatmap"].shape == (H, W)
    assert abs(out["pick_heatmap"].sum() - 1.0) < 1e-4 and 0 <= out["place_rot"] < 2 * math.pi
    path = tmp_path / "agent.pt"
    agent.save_checkpoint(path)
    payload = torch.load(path, weights_only=True)
    assert payload["agent"] == agent.name
    assert payload["weight_sources"] == dict.fromkeys(agent_class(agent.name).weight_sources, "random")
    params = dict(agent.named_parameters())
    saved = sum(v.numel() for k, v in payload["state_dict"].items() if k in params)
    assert saved == sum(p.numel() for p in agent.trainable_parameters())  # no frozen weights saved
    buffers = {k.rsplit(".", 1)[-1] for k in payload["state_dict"] if k not in params}
    assert buffers <= {"running_mean", "running_var", "num_batches_tracked"}  # the U-Net batch norms' only
    torch.manual_seed(123)  # a different global seed must not matter
    loaded = PickPlaceAgent.from_pretrained(path)
    again = loaded.act(_scene(2), instruction)
    assert type(loaded) is type(agent)
    for key, value in out.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, again[key], err_msg=key)
        else:
            assert value == again[key], key


def test_language_changes_what_language_agents_do(trained) -> None:
    agent, _, _ = trained
    scene = _scene(3)
    a = agent.act(scene, INSTRUCTION if agent.uses_language else None)["place_heatmap"]
    if agent.uses_language:
        b = agent.act(scene, "pack the yellow block in the brown box")["place_heatmap"]
        assert not np.array_equal(a, b)
        with pytest.raises(ValueError, match="needs an instruction"):
            agent.act(scene, None)
    else:
        np.testing.assert_array_equal(a, agent.act(scene, "pack the yellow block in the brown box")["place_heatmap"])


def test_semantic_encoder_is_a_setting_recorded_in_checkpoints(tmp_path: Path, tiny_config) -> None:
    """--semantic-encoder: a ViT CLIP in the CLIP-only agent trains, and its checkpoint rebuilds the same
    encoder (the name is in the saved config) and acts identically."""
    torch.manual_seed(0)
    agent = make_agent("clip_only", tiny_config("clip_only", semantic_encoder="ViT-B-16"))
    assert agent.encoder.trunk_channels == (768,) * 5 and agent.encoder.sentence_dim == 512
    agent.train()
    optimizer_step(agent.compute_loss, _batch(), agent.make_optimizer())
    path = tmp_path / "vit.pt"
    agent.save_checkpoint(path)
    loaded = PickPlaceAgent.from_pretrained(path)
    assert loaded.config.semantic_encoder == "ViT-B-16"
    np.testing.assert_array_equal(
        agent.act(_scene(4), INSTRUCTION)["place_heatmap"], loaded.act(_scene(4), INSTRUCTION)["place_heatmap"]
    )


def test_unknown_semantic_encoder_is_one_clear_error() -> None:
    from cliport.errors import UserError

    with pytest.raises(UserError, match="RN50-quickgelu"):
        make_agent("two_stream", {"semantic_encoder": "RN50-quickgel"})
