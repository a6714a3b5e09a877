"""Training from recorded demos needs no simulator: ``cliport-train`` runs end to end with both ``pybullet`` and
``pybullet_data`` unimportable (a GPU machine may still be building PyBullet while it trains)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cliport.cli import demos as demos_cli
from cliport.cli.common import run_cli

# Runs ``cliport.cli.train.entry()`` with ``ARGV`` while every import of pybullet or pybullet_data fails (the
# command loads every task module, packing_object_set's too, when it resolves the task name), then prints which
# of them, or the simulator's loader, were imported after all.
BLOCKED_TRAIN = """
import importlib.abc, json, sys
BLOCKED = ("pybullet", "pybullet_data")
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} is blocked in this test")
sys.meta_path.insert(0, Block())
import cliport.cli.train
sys.argv = ARGV
cliport.cli.train.entry()
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED + ("cliport.env.bullet",))))
"""


@pytest.fixture(scope="module")
def recorded_demos(tmp_path_factory: pytest.TempPathFactory) -> str:
    """Two place-red-in-green demos recorded by the simulator (in this process, where it is importable)."""
    root = str(tmp_path_factory.mktemp("demos"))
    argv = ["--task", "place-red-in-green", "--n", "2", "--data-dir", root, "--camera-scale", "0.5", "--no-progress"]
    run_cli(lambda: demos_cli.main(argv))
    return root


def test_cliport_train_from_recorded_demos_imports_no_simulator(recorded_demos: str, tmp_path) -> None:
    # No --n-rotations: the parser, and the task registry it asks for the default place rotations, once imported
    # the simulator, and training on a machine without PyBullet died at its start.
    run = tmp_path / "run"
    argv = [
        "cliport-train", "--agent", "transporter_only", "--task", "place-red-in-green", "--n-demos", "2",
        "--n-steps", "4", "--batch-size", "1", "--data-dir", recorded_demos, "--run-dir", str(run),
        "--device", "cpu", "--num-workers", "0", "--val-episodes", "0", "--width", "0.125", "--crop-size", "32",
        "--camera-scale", "0.5", "--checkpoint-steps", "2", "--checkpoint-every", "0", "--log-every", "2",
        "--no-progress",
    ]  # fmt: skip
    code = BLOCKED_TRAIN.replace("ARGV", repr(argv))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.strip().splitlines()
    assert json.loads(lines[-1]) == []  # neither simulator module, nor the module that loads them
    summary = json.loads("\n".join(lines[:-1]))
    assert summary["steps"] == 4 and summary["checkpoints"] == [2, 4]
    with open(run / "metrics.csv") as f:
        assert [row.split(",")[0] for row in f.read().split()[1:]] == ["2", "4"]
    assert (run / "checkpoints" / "last.pt").exists() and (run / "model.safetensors").exists()
