"""scripts/score_by_named.py: an unseen-colours evaluation's scores split by which colour words its instructions
name, per file and pooled; older results have their instructions read back from their scenes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cliport.errors import ConfigError
from cliport.evaluation.instruction_following import scene_instruction
from cliport.pretrain.transfer import named_colors, named_group
from cliport.utils.files import write_json

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "score_by_named.py"
TASK = "put-block-in-bowl-unseen-colors"


def _result(path: Path, episodes: list[tuple[str | None, float]]) -> str:
    rows = []
    for seed, (instruction, reward) in enumerate(episodes, start=10001):
        row = {"seed": seed, "total_reward": reward, "actions": 2}
        if instruction is not None:
            row["instruction"] = instruction
        rows.append(row)
    write_json(str(path), {"task": TASK, "mode": "test", "n_episodes": len(rows), "episodes": rows})
    return str(path)


def test_groups_per_file_and_pooled(tmp_path: Path, run_script) -> None:
    a = _result(tmp_path / "a.json", [
        ("put the pink blocks in a green bowl", 1.0),  # block unseen
        ("put the red blocks in a white bowl", 0.5),  # bowl unseen
        ("put the orange blocks in a purple bowl", 0.0),  # both
    ])  # fmt: skip
    b = _result(
        tmp_path / "b.json", [("put the blue blocks in a red bowl", 1.0), ("put the white blocks in a blue bowl", 0.0)]
    )
    done = run_script("score_by_named.py", a, b)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    first = report["files"][a]
    assert first["block_unseen"] == {"episodes": 1, "mean_score": 100.0, "ci95": [100.0, 100.0], "solved": 1}
    assert first["bowl_unseen"]["mean_score"] == 50.0 and first["bowl_unseen"]["solved"] == 0
    assert first["both_unseen"]["episodes"] == 1 and first["neither_unseen"]["episodes"] == 0
    pooled = report["pooled"]
    assert pooled["block_unseen"]["episodes"] == 2 and pooled["block_unseen"]["mean_score"] == 50.0
    assert pooled["neither_unseen"] == {"episodes": 1, "mean_score": 100.0, "ci95": [100.0, 100.0], "solved": 1}


def test_an_older_result_has_its_instructions_read_from_its_scenes(tmp_path: Path, run_script) -> None:
    path = _result(tmp_path / "old.json", [(None, 1.0)])
    with pytest.raises(ConfigError, match="record no instruction; pass --rebuild"):
        run_script("score_by_named.py", path)
    done = run_script("score_by_named.py", "--rebuild", path)
    assert done.returncode == 0, done.stderr
    group = named_group(*named_colors(scene_instruction(TASK, 10001, camera_scale=0.5)))
    assert json.loads(done.stdout)["files"][path][group]["episodes"] == 1


def test_a_missing_file_is_one_error_line(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "none.json")], capture_output=True, text=True)
    assert done.returncode != 0 and done.stderr.strip().splitlines() == [
        f"error: no evaluation result at {tmp_path / 'none.json'}"
    ]
