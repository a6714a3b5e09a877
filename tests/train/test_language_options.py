"""Training with every recorded instruction and centred sentence features (the language lesson's options)."""

from __future__ import annotations

import json

import torch

from cliport.train.config import TrainConfig
from cliport.train.trainer import train


def test_training_fits_the_centring_on_every_recorded_instruction(
    tmp_path, make_variant_dataset, tiny_config, capsys
) -> None:
    make_variant_dataset(str(tmp_path))
    overrides = {
        "agent": "two_stream", "task": "put-one-block-in-bowl-seen-colors", "n_demos": 1, "n_steps": 1,
        "batch_size": 1, "data_dir": str(tmp_path), "run_dir": str(tmp_path / "run"), "device": "cpu",
        "num_workers": 0, "val_episodes": 0, "checkpoint_steps": [1], "checkpoint_every": 0,
        "every_instruction": True,
        "agent_config": tiny_config("two_stream", n_rotations=1, map_scale=0.5, crop_size=64, center_sentences=True),
    }  # fmt: skip
    train(TrainConfig.build(overrides), progress=False)
    assert "centred on the training set's 3 instructions" in capsys.readouterr().err
    payload = torch.load(tmp_path / "run" / "checkpoints" / "step-000001.pt", weights_only=True)
    assert payload["config"]["center_sentences"] is True and float(payload["state_dict"]["sentence_scale"]) > 1
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["every_instruction"] is True


def test_training_on_contrasting_pairs_is_recorded_and_reproducible(
    tmp_path, make_two_bowl_dataset, tiny_config
) -> None:
    make_two_bowl_dataset(str(tmp_path))

    def run(name: str) -> dict:
        overrides = {
            "agent": "two_stream", "task": "put-one-block-in-bowl-seen-colors", "n_demos": 1, "n_steps": 2,
            "batch_size": 1, "data_dir": str(tmp_path), "run_dir": str(tmp_path / name), "device": "cpu",
            "num_workers": 0, "val_episodes": 0, "checkpoint_steps": [2], "checkpoint_every": 0, "log_every": 1,
            "every_instruction": True, "pair_contrasts": True,
            "agent_config": tiny_config("two_stream", n_rotations=1, map_scale=0.5, crop_size=64),
        }  # fmt: skip
        train(TrainConfig.build(overrides), progress=False)
        assert json.loads((tmp_path / name / "config.json").read_text())["pair_contrasts"] is True
        return torch.load(tmp_path / name / "checkpoints" / "step-000002.pt", weights_only=True)["state_dict"]

    first, again = run("a"), run("b")
    for key, value in first.items():
        assert torch.equal(value, again[key]), key
