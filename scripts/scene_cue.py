"""Does a put-one-block-in-bowl scene give the instructed block (or bowl) away by where it lies?

The task places the instructed block first and the instructed bowl first, so the objects' positions could differ
by role. For each scene this records where the blocks and bowls lie, then asks how well position alone picks the
instructed one: simple rules (the block nearest the centre, farthest from the edge, ...) and a conditional logit
over those features and their squares, cross-validated over 5 folds. Near chance (1 in 3 blocks, 1 in 2 bowls)
means a language-blind agent cannot use the placement order. Prints one JSON object.

    python scripts/scene_cue.py --scenes 600 --mode train
"""

from __future__ import annotations

import json
import sys

import numpy as np

from cliport.cli.common import OneLineParser, run_cli
from cliport.env import heightmap
from cliport.errors import ConfigError

BOUNDS = heightmap.BOUNDS[:2]  # the workspace's x and y (m)
FEATURES = ("centre distance", "nearest of its kind", "nearest of the other kind", "edge distance", "x", "|y|")


def object_features(objects: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Positions (K, 2) of one kind and (M, 2) of the other -> (K, len(FEATURES)) per-object features."""
    centre = BOUNDS.mean(axis=1)
    rows = []
    for i, xy in enumerate(objects):
        rest = np.delete(objects, i, axis=0)
        edge = min(xy[0] - BOUNDS[0, 0], BOUNDS[0, 1] - xy[0], xy[1] - BOUNDS[1, 0], BOUNDS[1, 1] - xy[1])
        rows.append([
            np.linalg.norm(xy - centre),
            np.linalg.norm(rest - xy, axis=1).min() if len(rest) else 0.0,
            np.linalg.norm(others - xy, axis=1).min(),
            edge,
            xy[0],
            abs(xy[1]),
        ])  # fmt: skip
    return np.asarray(rows)


def cross_validated_logit(features: np.ndarray, goal: np.ndarray, folds: int = 5, steps: int = 2000) -> float:
    """Features (S, K, F) of each scene's K candidates and the goal's index (S,) -> the held-out accuracy of a
    conditional logit over the standardised features and their squares, ``folds``-fold."""
    flat = features.reshape(-1, features.shape[-1])
    z = (features - flat.mean(0)) / (flat.std(0) + 1e-9)
    z = np.concatenate([z, z**2], axis=-1)
    fold = np.arange(len(goal)) % folds
    onehot = np.eye(features.shape[1])[goal]
    hits = 0
    for k in range(folds):
        train, test = fold != k, fold == k
        w = np.zeros(z.shape[-1])
        for _ in range(steps):
            s = z[train] @ w
            p = np.exp(s - s.max(1, keepdims=True))
            p /= p.sum(1, keepdims=True)
            w += 0.5 * np.einsum("snf,sn->f", z[train], onehot[train] - p) / train.sum()
        hits += int((np.argmax(z[test] @ w, axis=1) == goal[test]).sum())
    return hits / len(goal)


def position_cue(features: np.ndarray, goal: np.ndarray) -> dict[str, object]:
    """How well position picks the goal: each feature's rules (the largest, the smallest; ties to no one) and the
    cross-validated logit, with the chance rate and a 95 % half-width for the logit's accuracy."""
    chance = 1 / features.shape[1]
    rules = {}
    for j, name in enumerate(FEATURES):
        column = features[:, :, j]
        for how, best in (("largest", column.max(axis=1)), ("smallest", column.min(axis=1))):
            unique = (column == best[:, None]).sum(axis=1) == 1  # a tie picks no one
            rules[f"{how} {name}"] = round(float(np.mean(unique & (column[np.arange(len(goal)), goal] == best))), 4)
    accuracy = cross_validated_logit(features, goal)
    half = 1.96 * np.sqrt(accuracy * (1 - accuracy) / len(goal))
    return {"chance": round(chance, 4), "rules": rules, "logit": round(accuracy, 4), "logit_ci95": round(half, 4)}


def collect(task_name: str, mode: str, seeds: list[int]) -> list[dict[str, object]]:
    """Each scene's block and bowl positions (m), the instructed ones first as the task places them."""
    from tqdm import tqdm

    from cliport.env.environment import EnvConfig, Environment
    from cliport.evaluation.instruction_following import block_poses, lesson_task

    task = lesson_task(task_name, mode, "the position check")
    scenes = []
    with Environment(EnvConfig.defaults(camera_scale=0.25), task=task) as env:
        for seed in tqdm(seeds, desc="scenes", file=sys.stderr):
            env.reset(seed=seed)
            poses = block_poses(task)
            scenes.append({
                "blocks": [poses[c][0].tolist() for c in task.block_colors],
                "goal_block": list(task.block_colors).index(task.goal_block),
                "bowls": [list(task.bowl_colors[c][0][:2]) for c in task.bowl_colors],
                "goal_bowl": list(task.bowl_colors).index(task.goal_bowl),
            })  # fmt: skip
    return scenes


def main() -> None:
    parser = OneLineParser(prog="scene_cue.py", description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="put-one-block-in-bowl-seen-colors")
    parser.add_argument("--mode", default="train", choices=("train", "val", "test"))
    parser.add_argument("--scenes", type=int, default=600)
    args = parser.parse_args()
    if args.scenes < 10:
        raise ConfigError(f"--scenes must be at least 10 (5 folds), got {args.scenes}")
    from cliport.data.seeds import episode_seeds

    scenes = collect(args.task, args.mode, episode_seeds(args.mode, args.scenes))
    report: dict[str, object] = {"task": args.task, "mode": args.mode, "scenes": len(scenes)}
    for kind, other, goal in (("blocks", "bowls", "goal_block"), ("bowls", "blocks", "goal_bowl")):
        features = np.stack([object_features(np.asarray(s[kind]), np.asarray(s[other])) for s in scenes])
        report[kind] = position_cue(features, np.asarray([s[goal] for s in scenes]))
    from cliport.utils.machine import measurement_environment

    report["environment"] = measurement_environment()
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    run_cli(main)
