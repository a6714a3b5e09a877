"""save_pretrained / from_pretrained: safetensors weights that load without pickle into an agent that acts
exactly like the original; runs from before safetensors still load; bad input is one clear error."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from cliport.agents import PickPlaceAgent, make_agent
from cliport.agents.transporter_only import TransporterOnlyAgent
from cliport.agents.two_stream import TwoStreamAgent
from cliport.errors import CheckpointError, ConfigError, RunDirError
from cliport.utils.files import write_json
from cliport.utils.run_dir import RunDir


def _obs(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8),
            "height": rng.uniform(0, 0.1, (320, 160)).astype(np.float32)}  # fmt: skip


def _assert_same_actions(a: PickPlaceAgent, b: PickPlaceAgent, instruction: str | None = None) -> None:
    x, y = a.act(_obs(), instruction), b.act(_obs(), instruction)
    assert (x["pick_pix"], x["place_pix"], x["place_bin"]) == (y["pick_pix"], y["place_pix"], y["place_bin"])
    assert x["pose0"] == y["pose0"] and x["pose1"] == y["pose1"]
    np.testing.assert_array_equal(x["pick_heatmap"], y["pick_heatmap"])
    np.testing.assert_array_equal(x["place_heatmap"], y["place_heatmap"])


def _assert_same_weights(a: PickPlaceAgent, b: PickPlaceAgent) -> None:
    assert type(a) is type(b) and a.config == b.config
    x, y = a.trainable_state_dict(), b.trainable_state_dict()
    assert x.keys() == y.keys()
    for key, value in x.items():
        torch.testing.assert_close(y[key], value, rtol=0, atol=0)


@pytest.fixture(scope="module")
def transporter(tiny_config) -> PickPlaceAgent:
    torch.manual_seed(0)
    return make_agent("transporter_only", tiny_config("transporter_only", n_rotations=4))


def test_save_pretrained_then_from_pretrained_acts_identically_without_pickle(transporter, tmp_path, monkeypatch):
    folder = transporter.save_pretrained(tmp_path / "tiny")
    assert sorted(os.listdir(folder)) == ["config.json", "model.safetensors"]
    with open(os.path.join(folder, "config.json")) as f:
        config = json.load(f)
    assert config["agent"] == "transporter_only" and config["config"]["width"] == 0.125 and config["format"] == 2

    def refuse(*args, **kwargs):
        raise AssertionError("something was unpickled")

    with monkeypatch.context() as m:  # nothing below may unpickle
        for module, name in ((torch, "load"), (pickle, "load"), (pickle, "loads"), (pickle, "Unpickler")):
            m.setattr(module, name, refuse)
        weights = load_file(os.path.join(folder, "model.safetensors"))  # others need no cliport code
        agent = PickPlaceAgent.from_pretrained(folder)
        same_class = TransporterOnlyAgent.from_pretrained(os.path.join(folder, "model.safetensors"))
    assert weights.keys() == transporter.trainable_state_dict().keys()
    assert type(agent) is TransporterOnlyAgent
    _assert_same_actions(transporter, agent)
    _assert_same_weights(transporter, same_class)


def test_two_stream_keeps_frozen_clip_out_and_reloads_it_from_its_source(tmp_path, tiny_config) -> None:
    torch.manual_seed(0)
    original = make_agent("two_stream", tiny_config("two_stream", n_rotations=4))
    folder = original.save_pretrained(tmp_path / "ts")
    weights = load_file(os.path.join(folder, "model.safetensors"))
    assert weights.keys() == original.trainable_state_dict().keys()
    assert len(weights) < len(original.state_dict())  # the CLIP encoder is not in the file
    agent = TwoStreamAgent.from_pretrained(folder)
    assert agent.clip_source() == "random"
    _assert_same_actions(original, agent, "put the red block in the green bowl")


def _old_run(root, agent: PickPlaceAgent) -> str:
    """A run folder as cliport wrote it before safetensors: config.json, .pt checkpoints, val.json."""
    run = RunDir(str(root))
    os.makedirs(root, exist_ok=True)
    write_json(run.config, {"agent": agent.name, "task": "place-red-in-green"})
    for step in (1, 2):
        agent.save_checkpoint(run.checkpoint(step))
    agent.save_checkpoint(run.checkpoint("last"))
    write_json(run.val, {"best_step": 1, "checkpoints": {"1": {"mean_score": 10.0}, "2": {"mean_score": 0.0}}})
    return run.root


def test_runs_written_before_safetensors_still_load(transporter, tmp_path) -> None:
    root = _old_run(tmp_path / "old", transporter)
    _assert_same_actions(transporter, PickPlaceAgent.from_pretrained(root))  # newest scheduled .pt
    for which in ("best", "last", 2, "2"):
        _assert_same_weights(transporter, PickPlaceAgent.from_pretrained(root, checkpoint=which))
    _assert_same_weights(transporter, PickPlaceAgent.from_pretrained(RunDir(root).checkpoint(2)))  # a .pt file


def test_bad_sources_are_clear_errors(transporter, tmp_path) -> None:
    with pytest.raises(RunDirError, match="no run folder or weights file at"):
        PickPlaceAgent.from_pretrained(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunDirError, match="holds no model.safetensors and no scheduled checkpoints"):
        PickPlaceAgent.from_pretrained(tmp_path / "empty")
    folder = transporter.save_pretrained(tmp_path / "tiny")
    path = os.path.join(folder, "model.safetensors")
    with pytest.raises(CheckpointError, match="holds a transporter_only agent, not a two_stream one"):
        TwoStreamAgent.from_pretrained(folder)
    with pytest.raises(ConfigError, match="needs a run folder"):
        PickPlaceAgent.from_pretrained(path, checkpoint="best")
    with pytest.raises(ConfigError, match="--checkpoint must be"):
        PickPlaceAgent.from_pretrained(_old_run(tmp_path / "old", transporter), checkpoint="7")

    truncated = tmp_path / "truncated.safetensors"
    with open(path, "rb") as f:
        truncated.write_bytes(f.read()[:5000])
    with pytest.raises(CheckpointError, match="truncated or not a safetensors file"):
        PickPlaceAgent.from_pretrained(truncated)
    foreign = tmp_path / "foreign.safetensors"
    save_file({"w": torch.zeros(3)}, str(foreign))
    with pytest.raises(CheckpointError, match="not a cliport weights file"):
        PickPlaceAgent.from_pretrained(foreign)
    newer = tmp_path / "newer.safetensors"
    metadata = {"format": "3", "agent": "transporter_only", "config": "{}"}
    save_file({"w": torch.zeros(3)}, str(newer), metadata=metadata)
    with pytest.raises(CheckpointError, match="written by a newer cliport"):
        PickPlaceAgent.from_pretrained(newer)


def test_save_pretrained_refuses_a_training_run_folder(transporter, tmp_path) -> None:
    root = _old_run(tmp_path / "run", transporter)
    with pytest.raises(RunDirError, match="holds a training run"):
        transporter.save_pretrained(root)
