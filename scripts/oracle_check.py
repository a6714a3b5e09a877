"""Run a task's scripted oracle over seeds and print its success rate as JSON.

Usage: python scripts/oracle_check.py --task place-red-in-green --episodes 100 [--mode train] [--workers 2]
       python scripts/oracle_check.py --task towers-of-hanoi --seeds 14 28   (re-run chosen seeds)
Uses the same rollout code as demonstration generation (one environment per worker process).
Success = total reward > 0.99. A task group name (e.g. multi-ravens) prints one line per task.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing as mp
import statistics
import sys

from tqdm import tqdm

from cliport import tasks
from cliport.data import generate
from cliport.data.seeds import episode_seeds


def check(
    task_name: str,
    episodes: int,
    mode: str = "train",
    camera_scale: float = 1.0,
    progress: bool = True,
    workers: int = 1,
    seeds: list[int] | None = None,
) -> dict:
    """Oracle statistics of ``task_name`` over the first ``episodes`` protocol seeds of ``mode`` (or ``seeds``)."""
    seeds = seeds if seeds is not None else episode_seeds(mode, episodes)
    init = (task_name, mode, camera_scale)
    bar = tqdm(total=len(seeds), desc=task_name, disable=not progress, leave=False)
    results = []
    if workers == 1:
        generate.init_worker(*init)
        for seed in seeds:
            results.append(generate.check_seed(seed))
            bar.update(1)
    else:
        ctx = mp.get_context("spawn")
        with cf.ProcessPoolExecutor(workers, mp_context=ctx, initializer=generate.init_worker, initargs=init) as pool:
            for result in pool.map(generate.check_seed, seeds):
                results.append(result)
                bar.update(1)
    bar.close()
    failures = [{"seed": r["seed"], "total_reward": round(r["total_reward"], 3)} for r in results if not r["success"]]
    return {
        "task": task_name,
        "mode": mode,
        "episodes": len(results),
        "success_rate": sum(r["success"] for r in results) / len(results),
        "mean_reward": round(statistics.mean(r["total_reward"] for r in results), 4),
        "seconds_per_episode": round(statistics.mean(r["seconds"] for r in results), 2),
        "camera_scale": camera_scale,
        "failed_seeds": failures,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True, help="task or task group (cliport-tasks lists them)")
    parser.add_argument("--episodes", type=int, default=100, help="first N seeds of the mode's protocol")
    parser.add_argument("--seeds", type=int, nargs="+", help="run these seeds instead")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument("--camera-scale", type=float, default=1.0)
    parser.add_argument("--workers", type=int, default=1, help="worker processes (one simulator each)")
    args = parser.parse_args()
    if args.episodes < 1 or args.workers < 1:
        sys.exit("error: --episodes and --workers must be >= 1")
    try:
        names = tasks.resolve(args.task)
        tasks.make(names[0], args.mode)
    except (KeyError, ValueError) as e:
        sys.exit(f"error: {e.args[0]}")
    for name in names:
        result = check(name, args.episodes, args.mode, args.camera_scale, workers=args.workers, seeds=args.seeds)
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
