"""scripts/scene_cue.py: position alone finds a goal placed by a rule, and nothing where the goal lies at random."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "scene_cue.py"


def _module():
    spec = importlib.util.spec_from_file_location("scene_cue", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _scenes(rng: np.random.Generator, n: int, goal_central: bool) -> tuple[np.ndarray, np.ndarray]:
    cue = _module()
    features, goals = [], []
    for _ in range(n):
        blocks = np.column_stack([rng.uniform(0.3, 0.7, 3), rng.uniform(-0.45, 0.45, 3)])
        if goal_central:  # the goal is the block nearest the centre
            blocks = blocks[np.argsort(np.linalg.norm(blocks - cue.BOUNDS.mean(axis=1), axis=1))]
        bowls = np.column_stack([rng.uniform(0.3, 0.7, 2), rng.uniform(-0.45, 0.45, 2)])
        features.append(cue.object_features(blocks, bowls))
        goals.append(0)
    return np.stack(features), np.asarray(goals)


def test_a_goal_placed_by_a_rule_is_found_and_a_random_one_is_not():
    cue = _module()
    rng = np.random.default_rng(0)
    report = cue.position_cue(*_scenes(rng, 200, goal_central=True))
    assert report["rules"]["smallest centre distance"] == 1.0 and report["logit"] > 0.9
    report = cue.position_cue(*_scenes(rng, 300, goal_central=False))
    assert abs(report["logit"] - 1 / 3) < 0.1 and report["chance"] == round(1 / 3, 4)
    assert max(report["rules"].values()) < 0.5


def test_too_few_scenes_is_one_line(one_error_line):
    done = subprocess.run([sys.executable, str(SCRIPT), "--scenes", "3"], capture_output=True, text=True, timeout=60)
    one_error_line(done.returncode, done.stderr, "--scenes must be at least 10")
