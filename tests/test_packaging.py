"""``cliport.tasks`` and ``cliport.configs`` import from a checkout, an installed copy, and from any directory; a
non-editable install holds every module."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import cliport

REPO = Path(__file__).resolve().parent.parent

# Prints where cliport, its tasks and its configs came from, then lists the tasks as `cliport-tasks` does.
_PROBE = """
import importlib.resources, cliport, cliport.tasks
from cliport.utils.config import read_defaults
print(cliport.__file__, cliport.tasks.__file__, importlib.resources.files("cliport.configs"), sep="\\n")
assert read_defaults("env")["sim_hz"] > 0
import runpy, sys
sys.argv = ["cliport-tasks"]
runpy.run_module("cliport.cli.tasks", run_name="__main__")
"""


def _dependency_path() -> str:
    """The test interpreter's third-party folders (a virtual environment inside the checkout included: its
    editable-install finder is not loaded under -S, so only this checkout's own folders can supply cliport)."""
    return os.pathsep.join(p for p in sys.path if "-packages" in p)


def _probe(cwd: Path, *front: Path) -> list[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([*map(str, front), _dependency_path()])}
    # -S: no site hooks, so an editable install of this checkout cannot help; -c puts cwd first on sys.path.
    out = subprocess.run(
        [sys.executable, "-S", "-c", _PROBE], cwd=cwd, env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "place-red-in-green" in out.stdout and "multi-language-conditioned" in out.stdout
    return out.stdout.splitlines()[:3]


def test_checkout_locations_only_for_a_checkout(tmp_path: Path) -> None:
    checkout = tmp_path / "repo"
    for folder in ("cliport", "tasks", "configs"):
        (checkout / folder).mkdir(parents=True)
        (checkout / folder / "__init__.py").write_text("")
    assert cliport.checkout_locations(str(checkout / "cliport")) == {}  # no pyproject.toml: not a checkout
    (checkout / "pyproject.toml").write_text("")
    assert cliport.checkout_locations(str(checkout / "cliport")) == {
        "cliport.tasks": str(checkout / "tasks"),
        "cliport.configs": str(checkout / "configs"),
    }
    (checkout / "cliport" / "tasks").mkdir()  # installed layout: the subpackage is inside
    assert list(cliport.checkout_locations(str(checkout / "cliport"))) == ["cliport.configs"]


def test_source_checkout_without_install() -> None:
    paths = _probe(REPO)
    assert paths == [str(REPO / "cliport" / "__init__.py"), str(REPO / "tasks" / "__init__.py"), str(REPO / "configs")]


def test_non_editable_install_from_the_repository_root_and_elsewhere(tmp_path: Path) -> None:
    source = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("cliport", "tasks", "configs"):
        shutil.copytree(REPO / folder, source / folder, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    target = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(source)]
    out = subprocess.run(pip, capture_output=True, text=True, timeout=300)
    if out.returncode != 0 and "from versions: none" in out.stderr:
        pytest.skip(f"no build backend available offline: {out.stderr.strip().splitlines()[-1]}")
    assert out.returncode == 0, out.stderr[-3000:]
    installed = target / "cliport"
    assert (installed / "tasks" / "__init__.py").is_file() and (installed / "configs" / "env.toml").is_file()
    # Every module of the checkout is installed: pyproject.toml's list of packages misses no subpackage.
    modules = [p.relative_to(REPO / "cliport") for p in (REPO / "cliport").rglob("*.py")]
    assert [str(m) for m in modules if not (installed / m).is_file()] == []
    assert (installed / "models" / "encoders" / "clip_encoder.py").is_file()
    # And its package data: the published numbers the study reads.
    data = [p.relative_to(REPO / "cliport") for p in (REPO / "cliport" / "published").glob("*.json")]
    assert len(data) == 2 and [str(d) for d in data if not (installed / d).is_file()] == []

    # From the root the checkout's cliport/ shadows the installed one; its tasks must come from the checkout.
    assert _probe(REPO, target) == [
        str(REPO / "cliport" / "__init__.py"),
        str(REPO / "tasks" / "__init__.py"),
        str(REPO / "configs"),
    ]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    assert _probe(elsewhere, target) == [
        str(installed / "__init__.py"),
        str(installed / "tasks" / "__init__.py"),
        str(installed / "configs"),
    ]
