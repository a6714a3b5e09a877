import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "pretrain_experiment.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


def _row(arm: str, demos: int, unseen_solved: int, seed: int = 0) -> dict:
    seen = {"task": "put-one-block-in-bowl-seen-colors", "solved": 9, "episodes": 10, "followed": 8, "swaps": 10}
    named = {"solved": unseen_solved, "episodes": 10, "followed": unseen_solved, "swaps": 10}
    by_named = {
        "block_unseen": {"followed": unseen_solved, "swaps": 6},
        "both_unseen": {"followed": 0, "swaps": 4},
        "bowl_unseen": {"followed": 3, "swaps": 5},
        "neither_unseen": {"followed": 5, "swaps": 5},
    }
    return {"arm": arm, "demos": demos, "seed": seed, "seen": seen,
            "unseen": {"unseen_named": named, "by_named": by_named}}  # fmt: skip


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
    rows = [_row("random", 10, 1), _row("random", 10, 1, seed=1), _row("random", 30, 2), _row("random", 30, 4, seed=1)]
    (out / "grid.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    done = _run(
        "--arms", "random", "--semantic-encoder", "cliport-RN-tiny", "--demos", "10", "30", "--seeds", "0", "1",
        "--out", str(out)
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("done before") == 4 and not (out / "cells").exists()
    assert "random n=30  seed 0: seen solved 9/10, followed 8/10; naming unseen colours solved 2/10" in done.stdout
    table = (out / "grid.md").read_text().splitlines()
    assert table[2 + 2] == "| random | 30 | 0 | - | 9/10 | 8/10 | 2/10 | 2/10 |"
    # pooled over seeds 0 and 1 of 30 demos: unseen blocks (2 + 0) + (4 + 0) of 20, seen blocks 8 + 8 of 20
    pooled = table[table.index("Pooled over seeds:") + 5]
    assert pooled.startswith("| random | 30 | 0, 1 | 18/20 (90 %, 70-97) | 16/20 (80 %, 58-92) | 6/20 (30 %, 15-52) |")
    assert pooled.endswith("| 16/20 (80 %, 58-92) |")
    assert (out / "demo_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_each_arm_passes_its_similarity_flags_to_the_lesson():
    import argparse
    import importlib.util

    spec = importlib.util.spec_from_file_location("pretrain_experiment_flags", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    args = argparse.Namespace(weights="w.safetensors", semantic_encoder="cliport-RN-tiny")
    flags = {arm: module.arm_flags(arm, args) for arm in module.ARMS}
    assert flags["random"][:2] == ["--clip-weights", "random"] and "--similarity-maps" not in flags["pretrained"]
    assert flags["pretrained-maps-only"][-2:] == ["--similarity-maps", "--no-language-gates"]
    assert flags["pretrained-bank"][-2:] == ["--similarity-maps", "--similarity-bank"]
    assert flags["pretrained-bank-only"][-3:] == ["--similarity-maps", "--similarity-bank", "--no-language-gates"]
    assert flags["published"] == ["--clip-weights", "openai"]
