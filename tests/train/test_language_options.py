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
