"""scripts/bench_act.py and scripts/compare_renderers.py run and report JSON."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def _run(script: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPTS / script), *args], capture_output=True, text=True, timeout=600)


def test_bench_act_on_the_cpu_finds_no_batch_size_dependence():
    out = _run(
        "bench_act.py", "--device", "cpu", "--agent", "transporter_only", "--width", "0.125",
        "--tasks", "block-insertion", "--seeds", "2", "--sizes", "2",
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["device"] == "cpu" and report["observations"] == 2
    active = report["active_device_options"]
    assert active.pop("fused_adam") and not any(active.values()) and "graph_memory" not in report
    result = report["batch_size_agreement"]["batch_2_vs_1"]
    assert result["n"] == 2 and result["same_pick"] == result["same_place"] == 1.0
    assert result["max_heatmap_difference_over_peak"] < 1e-5


def test_compare_renderers_reports_the_differences():
    out = _run("compare_renderers.py", "--tasks", "block-insertion", "--camera-scale", "0.5")
    if out.returncode != 0 and "eglRenderer plugin did not load" in out.stderr:
        pytest.skip("PyBullet's EGL plugin does not load here")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)["block-insertion"]
    assert result["renderers"][0].startswith("cpu") and result["renderers"][1].startswith("egl")
    assert 0.0 <= result["color_pixels_differing"] <= 1.0 and result["height_p99_abs_difference_mm"] >= 0.0
