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
