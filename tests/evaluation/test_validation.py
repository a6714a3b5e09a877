"""Validation after training and beside it (a background process) give the same val.json."""

import pytest

from cliport.cli import train as train_cli
from cliport.cli.common import run_cli
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir


def _train(data_dir: str, run_dir: str, mode: str) -> None:
    argv = [
        "--agent", "transporter_only", "--task", "place-red-in-green", "--n-demos", "2", "--n-steps", "4",
        "--batch-size", "1", "--data-dir", data_dir, "--run-dir", run_dir, "--num-workers", "0",
        "--val-episodes", "1", "--val-workers", "1", "--val-mode", mode, "--camera-scale", "0.5",
        "--checkpoint-steps", "2", "--checkpoint-every", "0", "--no-progress", "--device", "cpu",
        "--width", "0.125", "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32",
    ]  # fmt: skip
    run_cli(lambda: train_cli.main(argv))


def test_validation_beside_training_matches_validation_after_it(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    after, beside = str(tmp_path / "after"), str(tmp_path / "beside")
    _train(str(tmp_path), after, "after")
    _train(str(tmp_path), beside, "beside")
    a, b = read_json(RunDir(after).val), read_json(RunDir(beside).val)
    assert set(a["checkpoints"]) == {"2", "4"} and a == b


def test_bad_val_mode_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        _train(str(tmp_path), str(tmp_path / "run"), "sometimes")
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and err == ["error: val_mode must be auto, after or beside, got 'sometimes'"]
