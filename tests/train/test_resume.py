"""Resuming optimiser state in another layout: NCHW Adam moments into channels_last parameters and back."""

from __future__ import annotations

import os

import pytest
import torch

from cliport.agents import PickPlaceAgent, make_agent
from cliport.agents.loss import optimizer_step
from cliport.train.config import TrainConfig
from cliport.train.resume import load_optimizer_state
from cliport.train.trainer import train
from cliport.utils.files import load_torch, save_torch
from cliport.utils.run_dir import RunDir


def _batch(seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "color": torch.randint(0, 255, (2, 64, 32, 3), dtype=torch.uint8, generator=g),
        "height": torch.rand(2, 64, 32, generator=g) * 0.05,
        "pick_pix": torch.tensor([[10, 5], [40, 20]]),
        "place_pix": torch.tensor([[50, 10], [20, 25]]),
        "place_rot": torch.tensor([1, 3]),
    }


def _agent(config: dict, layout: torch.memory_format) -> PickPlaceAgent:
    torch.manual_seed(0)
    agent = make_agent("transporter_only", config)
    for head in (agent.pick, agent.place):
        head.to(memory_format=layout)
        head.input_memory_format = layout
    return agent


def _saved_run(config: dict, layout: torch.memory_format) -> tuple[dict, dict]:
    """Weights and optimiser state after two training steps, the moments in ``layout`` (as a run whose
    parameters were in that layout saves them; trained in NCHW, since channels_last backward crashes on
    the CPU in torch 2.14, which the CPU path never uses)."""
    agent = _agent(config, torch.contiguous_format)
    optimizer = torch.optim.Adam(agent.trainable_parameters(), lr=1e-3, foreach=True)
    agent.train()
    for seed in (1, 2):
        optimizer_step(agent.compute_loss, _batch(seed), optimizer)
    state = optimizer.state_dict()
    for moments in state["state"].values():
        for key in ("exp_avg", "exp_avg_sq"):
            if moments[key].dim() == 4:
                moments[key] = moments[key].contiguous(memory_format=layout)
    return agent.state_dict(), state


def _resume(config: dict, weights: dict, state: dict, layout: torch.memory_format, fused: bool):
    agent = _agent(config, layout)
    agent.load_state_dict(weights)
    kind = {"fused": True} if fused else {"foreach": True}
    optimizer = torch.optim.Adam(agent.trainable_parameters(), lr=1e-3, **kind)
    load_optimizer_state(optimizer, state)
    return agent, optimizer


def _conv_weights(agent: PickPlaceAgent) -> list[torch.nn.Parameter]:
    return [p for p in agent.trainable_parameters() if p.dim() == 4 and p.shape[-1] > 1]


@pytest.mark.parametrize(
    ("saved", "resumed"),
    [(torch.contiguous_format, torch.channels_last), (torch.channels_last, torch.contiguous_format)],
    ids=["nchw-into-channels-last", "channels-last-into-nchw"],
)
def test_moments_take_the_parameters_layout(
    saved: torch.memory_format, resumed: torch.memory_format, tiny_config
) -> None:
    config = tiny_config("transporter_only", n_rotations=4)
    weights, state = _saved_run(config, saved)
    # What torch alone does: the moments keep the saved strides (fused CUDA Adam rejects that).
    plain_agent = _agent(config, resumed)
    plain = torch.optim.Adam(plain_agent.trainable_parameters(), lr=1e-3, fused=True)
    plain.load_state_dict(state)
    assert any(plain.state[p]["exp_avg"].stride() != p.stride() for p in _conv_weights(plain_agent))
    assert not plain.param_groups[0]["fused"]  # and the file's foreach Adam replaced the fused one

    agent, optimizer = _resume(config, weights, state, resumed, fused=True)
    assert optimizer.param_groups[0]["fused"] and optimizer.param_groups[0]["lr"] == 1e-3
    convs = _conv_weights(agent)
    assert convs and all(p.is_contiguous(memory_format=resumed) for p in convs)
    for p in agent.trainable_parameters():
        for key in ("exp_avg", "exp_avg_sq"):
            moment = optimizer.state[p][key]
            assert moment.stride() == p.stride() and moment.dtype == p.dtype and moment.device == p.device, key
        step = optimizer.state[p]["step"]
        assert step.dtype == torch.float32 and step.device == p.device and step.item() == 2

    # The layout changes no number: one more step with the same gradients matches a resume in the saved
    # layout (gradients set by hand, for the same reason as in _saved_run).
    reference, reference_optimizer = _resume(config, weights, state, saved, fused=False)
    g = torch.Generator().manual_seed(3)
    for p, q in zip(agent.trainable_parameters(), reference.trainable_parameters(), strict=True):
        grad = torch.randn(p.shape, generator=g)
        p.grad, q.grad = torch.empty_like(p).copy_(grad), torch.empty_like(q).copy_(grad)
    optimizer.step()
    reference_optimizer.step()
    for (name, a), b in zip(agent.state_dict().items(), reference.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7, msg=lambda m, name=name: f"{name}: {m}")


def test_a_run_saved_on_cuda_resumes_on_the_cpu(tmp_path, make_synthetic_dataset, monkeypatch, tiny_config) -> None:
    """The trainer's own resume path: a last.pt as CUDA writes it with fused Adam switched off (channels_last
    moments, foreach Adam) goes on training on the CPU with NCHW moments and the CPU's fused Adam."""
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    run_dir = str(tmp_path / "run")
    overrides = {
        "agent": "transporter_only", "task": "place-red-in-green", "n_demos": 2, "n_steps": 2, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": run_dir, "device": "cpu", "num_workers": 0, "val_episodes": 0,
        "checkpoint_steps": [2], "checkpoint_every": 0,
        "agent_config": tiny_config("transporter_only", n_rotations=4),
    }  # fmt: skip
    train(TrainConfig.build(overrides), progress=False)
    last = RunDir(run_dir).checkpoint("last")
    payload = load_torch(last)
    saved = payload["trainer"]["optimizer"]
    for moments in saved["state"].values():
        for key in ("exp_avg", "exp_avg_sq"):
            if moments[key].dim() == 4:
                moments[key] = moments[key].contiguous(memory_format=torch.channels_last)
    for group in saved["param_groups"]:
        group.update(fused=None, foreach=True)
    save_torch(payload, last)

    seen: dict[str, bool] = {}

    def checked(optimizer, state):
        load_optimizer_state(optimizer, state)
        params = [p for g in optimizer.param_groups for p in g["params"] if p.dim() == 4 and p.shape[-1] > 1]
        seen["strides_match"] = all(optimizer.state[p]["exp_avg"].stride() == p.stride() for p in params)
        seen["nchw"] = all(p.is_contiguous() for p in params)
        seen["fused"] = bool(optimizer.param_groups[0]["fused"]) and not optimizer.param_groups[0]["foreach"]

    monkeypatch.setattr("cliport.train.resume.load_optimizer_state", checked)
    summary = train(TrainConfig.build({**overrides, "n_steps": 4}), resume=True, progress=False)
    assert seen == {"strides_match": True, "nchw": True, "fused": True}
    assert summary["steps"] == 4 and os.path.exists(RunDir(run_dir).checkpoint(4))
