"""The workcell's settings apart from the simulator: training from demos imports no PyBullet."""

from __future__ import annotations

import subprocess
import sys

import pytest

from cliport.env import config as env_config
from cliport.env.config import EnvConfig, expected_renderer
from cliport.errors import ConfigError

BLOCK_PYBULLET = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("pybullet", "pybullet_data"):
            raise ImportError(f"{name} is blocked in this test")
sys.meta_path.insert(0, Block())
import cliport.train.trainer, cliport.cli.train
from cliport.env.config import EnvConfig, expected_renderer
print(EnvConfig.defaults(camera_scale=0.5).camera_scale, expected_renderer("cpu"))
"""


def test_the_trainer_imports_without_pybullet() -> None:
    # A GPU session trains while PyBullet still compiles beside it; only validation and evaluation need it.
    done = subprocess.run([sys.executable, "-c", BLOCK_PYBULLET], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["0.5", "tiny"]


def test_cliport_train_runs_from_demos_without_pybullet(tmp_path, make_synthetic_dataset) -> None:
    # Importing was not enough: the command's parser, and the task registry it asks for the default place
    # rotations (no --n-rotations here), once imported the simulator, and a lent GPU's cell died at its start.
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    run = tmp_path / "run"
    argv = [
        "cliport-train", "--agent", "transporter_only", "--task", "place-red-in-green", "--n-demos", "2",
        "--n-steps", "2", "--batch-size", "1", "--data-dir", str(tmp_path), "--run-dir", str(run), "--device",
        "cpu", "--num-workers", "0", "--val-episodes", "0", "--width", "0.125",
        "--crop-size", "32", "--camera-scale", "0.5", "--checkpoint-every", "0", "--no-progress",
    ]  # fmt: skip
    code = BLOCK_PYBULLET.replace("print(", f"sys.argv = {argv!r}\ncliport.cli.train.entry()\nprint(")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (run / "checkpoints" / "last.pt").exists() or list((run / "checkpoints").glob("step-*.pt"))
    assert "pybullet" not in done.stderr


def test_expected_renderer_follows_the_gpu_and_the_setting(monkeypatch) -> None:
    monkeypatch.setattr(env_config, "gpu_present", lambda: False)
    assert expected_renderer("auto") == "tiny"
    assert expected_renderer("cpu") == "tiny"
    assert env_config.renderer_choice("auto") == ("tiny", "no GPU")  # what an Environment names as its reason
    monkeypatch.setattr(env_config, "gpu_present", lambda: True)
    assert expected_renderer("egl") == "egl"
    with pytest.raises(ConfigError, match="renderer must be auto, egl or cpu, got 'gpu'"):
        expected_renderer("gpu")
    assert EnvConfig.defaults().renderer in ("auto", "egl", "cpu")
