"""scripts/gpu_check.sh: its argument errors, its dry run, and its CPU smoke run end to end (every stage tiny:
the CUDA tests skip, the benchmark at width 0.125, the cell 30 steps on 2 demos and 2 test episodes), then again
from the same folder, where every stage is found done."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "gpu_check.sh"


def _run(*args: str, timeout: int = 60, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout, env={**os.environ, **env}
    )


@pytest.mark.parametrize(
    "args, message",
    [
        (["--bogus"], "unknown option --bogus (see --help)"),
        (["--out"], "--out needs a value (see --help)"),
        (["--stages", "tests train"], "unknown stage train: choose from tests, bench, cell"),
        (["--reference-dir", "/nonexistent"], "--reference-dir /nonexistent holds no ref_bench.py"),
        (["--data-dir", "/nonexistent"], "--data-dir /nonexistent holds no assembling-kits-train demos"),
    ],
)
def test_bad_arguments_are_one_error_line(args: list[str], message: str) -> None:
    done = _run(*args)
    assert done.returncode == 2 and done.stderr == f"error: gpu_check.sh: {message}\n"


def test_help_says_what_it_checks() -> None:
    done = _run("--help")
    assert done.returncode == 0 and "--cpu" in done.stdout and "--reference-dir" in done.stdout


def test_without_cuda_it_points_to_the_cpu_run(tmp_path: Path) -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    done = _run("--out", str(tmp_path / "out"), "--stages", "tests")
    assert done.returncode == 2
    assert done.stderr.endswith(
        "torch sees no CUDA device here: check the driver, or run the CPU smoke run with --cpu\n"
    )


def test_dry_run_prints_each_stages_commands(tmp_path: Path) -> None:
    reference = tmp_path / "ref"
    reference.mkdir()
    (reference / "ref_bench.py").write_text("")
    out = tmp_path / "out"
    done = _run("--out", str(out), "--cell", "--reference-dir", str(reference), "--dry-run")
    assert done.returncode == 0, done.stderr
    assert not out.exists()  # a dry run writes nothing
    lines = done.stdout.splitlines()
    assert lines[0] == f"gpu_check: stages (tests bench cell) on cuda, results in {out}"
    runs = [line for line in lines if line.startswith("  would run: ")]
    assert "-m pytest -q -p no:cacheprovider -o addopts= -m gpu -rs tests" in runs[0]
    assert f"scripts/bench_train.py --profile --reference-dir {reference} --out {out}/state/bench.json" in runs[1]
    assert "cliport.cli.demos --task assembling-kits --mode train --n 100" in runs[2]
    assert "--agent transporter_only --recipe ravens --task assembling-kits --batch-size 1" in runs[3]
    assert "--n-demos 100 --n-steps 40000 --checkpoint-steps 1000 2000 5000 10000 20000 40000" in runs[3]
    assert "cliport.cli.eval" in runs[4] and "--n-episodes 100 --checkpoint 40000" in runs[4]
    assert lines[-4].split() == ["stage", "status", "result", "log"]
    assert [line.split()[:3] for line in lines[-3:]] == [
        ["tests", "not", "done"],
        ["bench", "not", "done"],
        ["cell", "not", "done"],
    ]


@pytest.mark.e2e
def test_cpu_smoke_run_then_every_stage_is_done(tmp_path: Path) -> None:
    out = tmp_path / "check"
    first = _run("--out", str(out), "--cell", timeout=1500, SMOKE="1")
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    table = first.stdout.splitlines()[-3:]
    assert table[0].split()[:2] == ["tests", "done"] and "skipped" in table[0]  # no CUDA: the CUDA tests skip
    assert table[1].split()[:3] == ["bench", "done", "transporter_only"]
    assert table[2].split()[:4] == ["cell", "done", "step", "30:"] and "of 2" in table[2]
    assert (out / "state" / "cell.json").exists() and (out / "cell" / "run" / "checkpoints" / "step-000030.pt").exists()
    assert (out / "summary.txt").read_text().splitlines()[1:] == table
    again = _run("--out", str(out), "--cell", timeout=120, SMOKE="1")
    assert again.returncode == 0, again.stderr
    assert [line.split(":")[0] for line in again.stdout.splitlines() if "done before" in line] == [
        "tests",
        "bench",
        "cell",
    ]
    assert again.stdout.splitlines()[-3:] == table
