import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "bench_model.py"
TINY = ["--agent", "transporter_only", "--width", "0.125", "--steps", "1"]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=900)


@pytest.mark.e2e
def test_reports_rates_memory_and_flops_as_json():
    out = _run(*TINY, "--batch-sizes", "1", "2", "--flops")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["device"] == "cpu" and report["width"] == 0.125 and report["clip_weights"] == "random"
    result = report["transporter_only"]
    assert result["act_latency_s"] > 0 and report["cpu_peak_rss_gib"] > 0
    assert result["train_samples_per_s_batch1"] > 0 and result["train_samples_per_s_batch2"] > 0
    # A training sample is act()'s forward passes plus their backward (about twice the forward).
    assert 2.0 < result["train_gflop_per_sample"] / result["act_gflop"] < 4.0


@pytest.mark.e2e
def test_profile_and_act_batch():
    out = _run(*TINY, "--batch-sizes", "1", "--profile", "--act-batch", "2")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)["transporter_only"]
    rows = result["profile_top_ops"]
    assert result["profile_device"] == "cpu" and len(rows) == 15
    assert all(row["total_ms"] > 0 and row["calls"] > 0 and 0 < row["share"] <= 1 for row in rows)
    assert [row["total_ms"] for row in rows] == sorted((row["total_ms"] for row in rows), reverse=True)
    assert result["act_batch2_latency_s"] > 0 and result["act_batch2_s_per_observation"] > 0


def test_cpu_defaults_are_small_and_help_names_paper_size():
    out = _run("--help")
    assert out.returncode == 0 and "--width 1 --batch-sizes 1 8" in " ".join(out.stdout.split())


def test_bad_width_is_one_line_error():
    out = _run("--width", "0")
    assert out.returncode == 2
    assert "--width" in out.stderr and "Traceback" not in out.stderr


@pytest.mark.slow
def test_bf16_autocast_runs():
    out = _run(*TINY, "--batch-sizes", "1", "--amp", "bf16")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["amp"] == "bf16"


@pytest.mark.e2e
def test_lesson_times_the_lessons_step_and_records_the_machine():
    out = _run("--lesson", "--steps", "1", "--repeats", "2", "--quickstart-args=--no-scale-up-mid")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    lesson = report["lesson"]
    assert (lesson["agent"], lesson["width"], lesson["map_scale"], lesson["n_rotations"]) == (
        "two_stream",
        0.125,
        0.5,
        1,
    )
    assert lesson["batch_size"] == 2 and lesson["pair_contrasts"] and lesson["scale_up_mid"] is False
    assert len(lesson["train_steps_per_s_repeats"]) == 2 and lesson["train_steps_per_s"] > 0
    environment = report["environment"]
    assert environment["cpu"]["cores"] >= 1
    assert environment["versions"]["torch"].split("+")[0] == torch.__version__.split("+")[0]
    assert "--lesson" in environment["command"]


def test_lesson_refuses_no_repeats():
    out = _run("--lesson", "--repeats", "0")
    assert out.returncode == 2
    assert "--repeats" in out.stderr and "Traceback" not in out.stderr
