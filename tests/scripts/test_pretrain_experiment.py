import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "pretrain_experiment.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


def _row(arm: str, demos: int, unseen_solved: int) -> dict:
    seen = {"task": "put-one-block-in-bowl-seen-colors", "solved": 9, "episodes": 10, "followed": 8, "swaps": 10}
    named = {"solved": unseen_solved, "episodes": 10, "followed": unseen_solved, "swaps": 10}
    return {"arm": arm, "demos": demos, "seed": 0, "seen": seen, "unseen": {"unseen_named": named}}


def test_arms_need_their_weights_and_model(tmp_path, one_error_line):
    out = str(tmp_path / "grid")
    done = _run("--arms", "pretrained", "--out", out)
    one_error_line(done.returncode, done.stderr, "the pretrained arm needs --weights FILE")
    done = _run("--arms", "random", "--out", out)
    one_error_line(done.returncode, done.stderr, "the random arm needs --semantic-encoder")
    done = _run("--arms", "random", "--semantic-encoder", "cliport-RN-tiny", "--demos", "0", "--out", out)
    one_error_line(done.returncode, done.stderr, "--demos must all be at least 1")


def test_finished_cells_are_not_run_again_and_are_summarised(tmp_path):
    out = tmp_path / "grid"
    out.mkdir()
    rows = [_row("random", 10, 1), _row("random", 30, 2)]
    (out / "grid.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    done = _run("--arms", "random", "--semantic-encoder", "cliport-RN-tiny", "--demos", "10", "30", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("done before") == 2 and not (out / "cells").exists()
    assert "random n=30  seed 0: seen solved 9/10, followed 8/10; naming unseen colours solved 2/10" in done.stdout
    table = (out / "grid.md").read_text().splitlines()
    assert len(table) == 4 and table[3] == "| random | 30 | 0 | - | 9/10 | 8/10 | 2/10 | 2/10 |"
    assert (out / "demo_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
