"""scripts/offline_bundle.sh without network: its argument errors, and the dry run's requirements and commands (every
dependency of pyproject.toml but PyBullet as wheels for each Python asked for, cliport's wheel, PyBullet's source)."""

from __future__ import annotations

import subprocess
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "offline_bundle.sh"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--bogus"], "unknown option --bogus (see --help)"),
        (["--python-version", "3.10"], "--python-version must be 3.11 or 3.12, got 3.10"),
        (["--arch", "ppc64le"], "--arch must be x86_64 or aarch64, got ppc64le"),
        (["--pybullet", "latest"], "--pybullet must be a version such as 3.2.7, got latest"),
        (["--extras", "gpu"], "unknown extra(s) gpu (pyproject.toml has dev, docs, cluster)"),
        (["--out"], "--out needs a value (see --help)"),
    ],
)
def test_bad_arguments_are_one_error_line(args: list[str], message: str) -> None:
    done = _run(*args)
    assert done.returncode == 2 and done.stderr == f"error: offline_bundle.sh: {message}\n"


def test_dry_run_lists_the_requirements_and_downloads_for_each_python(tmp_path: Path) -> None:
    out = tmp_path / "bundle"
    done = _run("--out", str(out), "--extras", "", "--index-url", "https://example.org/simple", "--dry-run")
    assert done.returncode == 0, done.stderr
    assert not out.exists()  # a dry run writes nothing
    lines = done.stdout.splitlines()
    assert lines[0] == f"offline bundle for Python 3.11 3.12 on Linux x86_64 in {out}"
    requirements = [line.strip() for line in lines[2 : lines.index(next(x for x in lines if x.startswith("would")))]]
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert requirements == [r for r in declared if not r.startswith("pybullet")] + ["setuptools>=68", "wheel"]
    runs = [line.removeprefix("would run: ") for line in lines if line.startswith("would run: ")]
    assert len(runs) == 4
    for version, command in zip(("3.11", "3.12"), runs[:2], strict=True):
        assert f"pip download --only-binary=:all: --implementation cp --python-version {version}" in command
        assert "--platform manylinux_2_28_x86_64" in command and "--platform manylinux2014_x86_64" in command
        assert f"--index-url https://example.org/simple -d {out}/wheels -r {out}/requirements.txt" in command
    assert runs[2].endswith(f"pip wheel --no-deps -w {out}/wheels {ROOT}")
    assert runs[3].endswith(f"-d {out} pybullet==3.2.7") and "--no-binary=:all:" in runs[3]
    assert "--no-build-isolation BUNDLE/pybullet-3.2.7.tar.gz" in done.stdout
    assert "pip install --no-index --find-links BUNDLE/wheels cliport\n" in done.stdout


def test_dry_run_with_the_dev_extra_for_one_python(tmp_path: Path) -> None:
    done = _run("--out", str(tmp_path), "--python-version", "3.12", "--arch", "aarch64", "--dry-run")
    assert done.returncode == 0, done.stderr
    assert "  pytest>=8" in done.stdout.splitlines() and "  pybullet" not in done.stdout
    downloads = [line for line in done.stdout.splitlines() if "--only-binary" in line]
    assert len(downloads) == 1 and "--python-version 3.12" in downloads[0]
    assert "--platform manylinux_2_28_aarch64" in downloads[0]
    assert "cliport[dev]" in done.stdout
