"""Run a task's scripted oracle over seeds and print its success rate as JSON.

Usage: python scripts/oracle_check.py --task place-red-in-green --episodes 100 [--mode train]
Uses the same rollout code as demonstration generation. Success = total reward > 0.99.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

from tqdm import tqdm

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.data.seeds import episode_seeds
from cliport.env.environment import EnvConfig, Environment


def check(task_name: str, episodes: int, mode: str = "train", camera_scale: float = 1.0, progress: bool = True) -> dict:
    task = tasks.make(task_name, mode)
    results = []
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        policy = oracle_policy(env)
        for seed in tqdm(episode_seeds(mode, episodes), desc=task_name, disable=not progress, leave=False):
            results.append(run_episode(env, seed, policy))
    failures = [{"seed": e.seed, "total_reward": round(e.total_reward, 3)} for e in results if not e.success]
    return {
        "task": task_name,
        "mode": mode,
        "episodes": len(results),
        "success_rate": sum(e.success for e in results) / len(results),
        "mean_reward": round(statistics.mean(e.total_reward for e in results), 4),
        "seconds_per_episode": round(statistics.mean(e.seconds for e in results), 2),
        "failed_seeds": failures,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument("--camera-scale", type=float, default=1.0)
    args = parser.parse_args()
    try:
        names = tasks.resolve(args.task)
    except KeyError as e:
        sys.exit(f"error: {e.args[0]}")
    for name in names:
        print(json.dumps(check(name, args.episodes, args.mode, args.camera_scale)), flush=True)


if __name__ == "__main__":
    main()
