"""Importing the simulator prints nothing (pybullet's C code prints its build time at import)."""

from __future__ import annotations

import subprocess
import sys


def test_importing_the_simulator_and_tasks_prints_nothing() -> None:
    code = "import cliport.env.environment, cliport.tasks; cliport.tasks.make('place-red-in-green', 'train')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stderr == "" and out.stdout == ""


def test_plain_pybullet_import_does_print() -> None:
    """The check above can fail: a bare import shows the banner this library hides."""
    out = subprocess.run([sys.executable, "-c", "import pybullet"], capture_output=True, text=True, timeout=60)
    assert "pybullet build time" in out.stderr
