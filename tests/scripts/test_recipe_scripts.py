"""scripts/recipe_arithmetic.py and scripts/recipe_curves.py: the recipes' first Adam step, and their curves."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

from cliport.utils.files import write_json

SCRIPTS = pathlib.Path(__file__).resolve().parents[2] / "scripts"


def _run(script: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPTS / script), *args], capture_output=True, text=True, timeout=600)


def test_recipe_arithmetic_cell_mean_puts_gradients_below_eps() -> None:
    done = _run("recipe_arithmetic.py", "--width", "0.125", "--n-rotations", "4")
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout)
    cliport, ravens = out["recipes"]["cliport"], out["recipes"]["ravens"]
    # The same sample's cross-entropy whatever the recipe; CLIPort's loss is it divided by the cells.
    assert cliport["pick_ce"] == ravens["pick_ce"] and cliport["place_ce"] == ravens["place_ce"]
    for net in ("pick", "place"):
        assert cliport[net]["share_of_gradients_below_eps"] > ravens[net]["share_of_gradients_below_eps"]
        assert cliport[net]["mean_move_over_lr"] < 0.1 * ravens[net]["mean_move_over_lr"]
        assert cliport[net]["median_abs_gradient"] < 1e-8


def _study(folder: str, task: str, scores: dict[str, list[list[float]]]) -> str:
    runs = []
    for recipe, per_seed in scores.items():
        seeds = [
            {
                "seed": seed,
                "checkpoints": [{"step": 100 * (i + 1), "val": v, "test": t} for i, (v, t) in enumerate(pairs)],
            }  # fmt: skip
            for seed, pairs in enumerate(per_seed)
        ]
        runs.append({"agent": "transporter_only", "recipe": recipe, "n_demos": 10, "per_seed": seeds})
    os.makedirs(folder)
    write_json(os.path.join(folder, "results.json"), {"task": task, "n_steps": 200, "runs": runs})
    return folder


def test_recipe_curves_plots_and_tabulates_every_seed(tmp_path) -> None:
    a = _study(str(tmp_path / "a"), "place-red-in-green", {"cliport": [[(40, 50), (60, 70)]], "ravens": [
        [(90, 95), (100, 100)], [(80, 85), (90, None)]]})  # fmt: skip
    b = _study(str(tmp_path / "b"), "block-insertion", {"ravens": [[(0, 5), (100, 95)]]})
    out = tmp_path / "fig" / "curves.png"
    done = _run("recipe_curves.py", a, b, "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert out.stat().st_size > 10_000
    rows = [line for line in done.stdout.splitlines() if line.startswith("| place") or line.startswith("| block")]
    assert len(rows) == 4
    assert "| ravens | 10 | 1 | 100: 80.0 / 85.0 / 200: 90.0 / - |" in done.stdout


def test_recipe_curves_names_a_folder_without_results(tmp_path, one_error_line) -> None:
    done = _run("recipe_curves.py", str(tmp_path))
    err = one_error_line(done.returncode, done.stderr, status=2)
    assert err == f"error: {tmp_path}: no results.json (run cliport-reproduce there first)"
