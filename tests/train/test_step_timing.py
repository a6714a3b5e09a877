"""The training-speed probe: real steps of the configured agent on a synthetic batch."""

from __future__ import annotations

import pytest
import torch

from cliport.train import step_timing
from cliport.train.config import TrainConfig


def _config(tmp_path, agent: str, **agent_config: object) -> TrainConfig:
    return TrainConfig.build({
        "agent": agent, "task": "put-one-block-in-bowl-seen-colors", "n_steps": 10, "batch_size": 1,
        "data_dir": str(tmp_path), "run_dir": str(tmp_path / "run"), "device": "cpu", "recipe": "ravens",
        "agent_config": {"width": 0.125, "n_rotations": 1, **agent_config},
    })  # fmt: skip


def test_the_probe_trains_the_configured_agent_and_leaves_the_random_state(tmp_path, monkeypatch) -> None:
    steps: list[tuple[str, int]] = []
    real = step_timing.TrainStep.__call__

    def counted(self, batch):
        steps.append((self.agent.name, batch["color"].shape[0]))
        return real(self, batch)

    monkeypatch.setattr(step_timing.TrainStep, "__call__", counted)
    torch.manual_seed(7)
    expected = torch.rand(3)
    torch.manual_seed(7)
    seconds = step_timing.step_seconds(
        _config(tmp_path, "two_stream", map_scale=0.5, clip_weights="random", center_sentences=True),
        steps=2,
        warmup=1,
    )
    assert torch.equal(torch.rand(3), expected)
    assert seconds > 0
    assert steps == [("two_stream", 1)] * 3


def test_the_probe_refuses_no_steps(tmp_path) -> None:
    with pytest.raises(ValueError, match="steps >= 1"):
        step_timing.step_seconds(_config(tmp_path, "transporter_only"), steps=0)


def test_probe_batches_show_new_images_and_pairs_as_training_does() -> None:
    alone = step_timing.probe_batches(4, batch_size=2)
    assert all(not torch.equal(a["color"], b["color"]) for a, b in zip(alone, alone[1:], strict=False))
    assert [b["lang"] for b in alone] == [list(step_timing.PROBE_INSTRUCTIONS)] * 4

    paired = step_timing.probe_batches(4, batch_size=1, pair_contrasts=True)
    assert torch.equal(paired[1]["color"], paired[0]["color"]) and torch.equal(paired[1]["height"], paired[0]["height"])
    assert paired[1]["lang"] != paired[0]["lang"]
    assert not torch.equal(paired[2]["color"], paired[1]["color"])
    assert torch.equal(paired[3]["color"], paired[2]["color"])


def test_probe_batches_of_two_hold_a_pair_as_training_does() -> None:
    batches = step_timing.probe_batches(3, batch_size=2, pair_contrasts=True)
    for batch in batches:
        assert torch.equal(batch["color"][1], batch["color"][0]) and torch.equal(batch["height"][1], batch["height"][0])
        assert batch["lang"] == list(step_timing.PROBE_INSTRUCTIONS)
        # The other instruction names another block: the pair's picks (and so its place nets' crops) differ.
        assert not torch.equal(batch["pick_pix"][1], batch["pick_pix"][0])
    assert not torch.equal(batches[1]["color"][0], batches[0]["color"][0])
