"""One version: pyproject.toml's, the installed metadata (what ``pip show cliport`` prints), ``cliport.__version__``
and every command's ``--version`` agree."""

from __future__ import annotations

import importlib.metadata
import runpy
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import cliport

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
STALE = "the installed metadata is not this checkout's: reinstall it (pip install -e .)"


def test_metadata_and_package_agree_with_pyproject():
    assert importlib.metadata.version("cliport") == PYPROJECT["version"], STALE
    assert cliport.__version__ == PYPROJECT["version"]


def _console_scripts() -> dict[str, importlib.metadata.EntryPoint]:
    return {
        ep.name: ep for ep in importlib.metadata.distribution("cliport").entry_points if ep.group == "console_scripts"
    }


def test_every_console_script_is_installed():
    assert sorted(_console_scripts()) == sorted(PYPROJECT["scripts"]), STALE


@pytest.mark.parametrize("name", sorted(PYPROJECT["scripts"]))
def test_every_command_prints_the_version(name, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [name, "--version"])
    with pytest.raises(SystemExit) as exit_info:
        _console_scripts()[name].load()()  # what the installed command runs
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"cliport {PYPROJECT['version']}\n"


def test_quickstart_prints_the_version(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["quickstart.py", "--version"])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(ROOT / "scripts" / "quickstart.py"), run_name="__main__")
    assert exit_info.value.code == 0
    assert capsys.readouterr().out == f"cliport {PYPROJECT['version']}\n"


def test_an_installed_command_prints_the_version():
    command = shutil.which("cliport-tasks", path=str(Path(sys.executable).parent))
    if command is None:
        pytest.skip("cliport-tasks is not installed beside this interpreter")
    out = subprocess.run([command, "--version"], capture_output=True, text=True, timeout=120)
    assert (out.returncode, out.stdout) == (0, f"cliport {PYPROJECT['version']}\n"), out.stderr
