import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "oracle_check.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=600)


def test_two_workers_report_the_protocol_seeds():
    out = _run("--task", "place-red-in-green", "--episodes", "2", "--workers", "2", "--camera-scale", "0.5")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["task"] == "place-red-in-green" and result["episodes"] == 2
    assert result["success_rate"] == 1.0 and result["failed_seeds"] == []
    assert result["mean_reward"] > 0.99 and result["seconds_per_episode"] > 0


def test_chosen_seeds_and_bad_task():
    out = _run("--task", "block-insertion", "--seeds", "4", "--camera-scale", "0.5")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["episodes"] == 1
    bad = _run("--task", "no-such-task")
    assert bad.returncode != 0
    assert "no-such-task" in bad.stderr and "Traceback" not in bad.stderr
