"""scripts/oracle_check.py and oracle_table.py: episodes, records that resume, the tables; bad input in one line.
Most calls run the scripts in this process (``run_script``); the bad task starts oracle_check.py as a process."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "oracle_check.py"


@pytest.fixture
def _run(run_script):
    return lambda *args: run_script("oracle_check.py", *args)


@pytest.fixture
def _table(run_script):
    return lambda *args: run_script("oracle_table.py", *args)


def test_two_workers_report_the_protocol_seeds(_run):
    out = _run("--task", "place-red-in-green", "--episodes", "2", "--workers", "2", "--camera-scale", "0.5")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["task"] == "place-red-in-green" and result["episodes"] == 2
    assert result["success_rate"] == 1.0 and result["failed_seeds"] == []
    assert result["mean_reward"] > 0.99 and result["seconds_per_episode"] > 0


def test_chosen_seeds_and_bad_task(_run, one_error_line):
    out = _run("--task", "block-insertion", "--seeds", "4", "--camera-scale", "0.5")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["episodes"] == 1
    bad = subprocess.run([sys.executable, str(SCRIPT), "--task", "no-such-task"], capture_output=True, text=True)
    one_error_line(bad.returncode, bad.stderr, "no-such-task")


def test_bad_worker_counts_are_one_clear_line(_run, one_error_line):
    for args, message in [
        (["--workers", "0"], "--workers must be >= 1, got 0"),
        (["--workers", "3", "--episodes", "2"], "--workers 3 is more than the 2 episode(s) to run"),
    ]:
        out = _run("--task", "block-insertion", *args)
        one_error_line(out.returncode, out.stderr, message)


def test_record_dir_resumes_and_survives_a_torn_line(tmp_path, _run, _table, one_error_line):
    records = tmp_path / "oracle"
    first = _run("--task", "block-insertion", "--episodes", "2", "--camera-scale", "0.5", "--record-dir", str(records))
    assert first.returncode == 0, first.stderr
    assert json.loads(first.stdout)["newly_run"] == 2
    path = records / "block-insertion.jsonl"
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["seed"] for r in lines] == [0, 2]
    assert all(r["task"] == "block-insertion" and r["camera_scale"] == 0.5 and "commit" in r for r in lines)
    with open(path, "a") as f:
        f.write('{"task": "block-insertion", "mode": "tr')  # a run killed mid-write
    again = _run("--task", "block-insertion", "--episodes", "3", "--camera-scale", "0.5", "--record-dir", str(records))
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    assert summary["newly_run"] == 1 and summary["episodes"] == 3 and summary["success_rate"] == 1.0
    assert json.loads(path.read_text().splitlines()[-1])["seed"] == 4

    shown = _table("--dir", str(records))
    assert shown.returncode == 0, shown.stderr
    row = [line for line in shown.stdout.splitlines() if line.startswith("| block-insertion")]
    assert len(row) == 1 and "first 3" in row[0] and "1.00 (3/3)" in row[0] and "cameras x0.5" in row[0]

    readme = tmp_path / "README.md"
    readme.write_text("# no markers here\n")
    bad = _table("--dir", str(records), "--readme", str(readme))
    one_error_line(bad.returncode, bad.stderr, "markers")
    readme.write_text("before\n<!-- oracle-table:start -->\nold\n<!-- oracle-table:end -->\nafter\n")
    good = _table("--dir", str(records), "--readme", str(readme))
    assert good.returncode == 0, good.stderr
    text = readme.read_text()
    assert text.startswith("before\n") and text.endswith("after\n")
    assert "old" not in text and "| block-insertion" in text


def test_blind_records_apart_from_the_oracle_and_its_table(tmp_path, _run, _table, one_error_line):
    records = tmp_path / "blind"
    task = "put-block-in-bowl-seen-colors"
    args = ("--task", task, "--episodes", "2", "--mode", "test", "--camera-scale", "0.5", "--record-dir", str(records))
    oracle = _run(*args)
    assert oracle.returncode == 0, oracle.stderr
    blind = _run("--blind", *args)
    assert blind.returncode == 0, blind.stderr
    summary = json.loads(blind.stdout)
    assert summary["policy"] == "blind" and summary["newly_run"] == 2  # the oracle's records are not the blind's
    lines = [json.loads(line) for line in (records / f"{task}.jsonl").read_text().splitlines()]
    assert [r.get("policy", "oracle") for r in lines] == ["oracle", "oracle", "blind", "blind"]

    blind_only = tmp_path / "blind-only"
    blind_only.mkdir()
    (blind_only / f"{task}.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines[2:]))
    out = tmp_path / "ceilings.json"
    shown = _table("--blind", "--dir", str(blind_only), "--json", str(out))
    assert shown.returncode == 0, shown.stderr
    row = [line for line in shown.stdout.splitlines() if line.startswith(f"| {task}")]
    assert len(row) == 1 and "| 62.7 | 64.7 |" in row[0]  # CLIPort's Transporter-only, 100 and 1000 demos
    ceiling = json.loads(out.read_text())["tasks"][task]
    expected = 100 * sum(r["total_reward"] for r in lines[2:]) / 2
    assert ceiling["episodes"] == 2 and abs(ceiling["score"] - expected) < 0.06
    assert ceiling["interval"][0] <= ceiling["score"] <= ceiling["interval"][1]
    bad = _table("--json", str(out), "--dir", str(blind_only))
    one_error_line(bad.returncode, bad.stderr, "--json goes with --blind")
