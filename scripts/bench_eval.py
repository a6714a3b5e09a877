"""Evaluation throughput: episodes per second with 1 and N simulator workers, as JSON.

Usage: python scripts/bench_eval.py --task block-insertion --episodes 8 --workers 1 2 [--camera-scale 0.5]
       python scripts/bench_eval.py --task assembling-kits --episodes 8 --oracle
The agent is a random tiny transporter_only by default (width 0.125, 4 rotations, crop 32), ``--checkpoint``
loads a trained one, ``--oracle`` runs the scripted expert inside the workers. Episodes/s counts from the
first episode's start to the last one's end; the workers' start-up is reported apart (``startup_s``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from cliport.env.environment import EnvConfig
from cliport.errors import UserError
from cliport.utils.machine import measurement_environment


def _agent(checkpoint: str | None, device: str):
    import torch

    from cliport.agents import PickPlaceAgent, make_agent
    from cliport.utils.device import resolve_device

    if checkpoint is not None:
        return PickPlaceAgent.from_pretrained(checkpoint, device=resolve_device(device))
    torch.manual_seed(0)
    tiny = {"width": 0.125, "n_rotations": 4, "crop_size": 32}
    return make_agent("transporter_only", tiny).to(resolve_device(device))


def bench(
    task: str, mode: str, episodes: int, workers: list[int], camera_scale: float, policy, progress: bool = False
) -> dict:
    """Time ``episodes`` episodes of ``task`` with each worker count; results per count and speed-ups."""
    from cliport.data.seeds import episode_seeds
    from cliport.evaluation.engine import EvalEngine, resolve_workers

    seeds = episode_seeds(mode, episodes)
    runs = []
    for n in workers:
        resolve_workers(n, episodes)
        begin = time.perf_counter()
        with EvalEngine(task, mode, EnvConfig.defaults(camera_scale=camera_scale), n, progress) as engine:
            rows = engine.run(policy, seeds)
            timing = engine.last_timing
        runs.append(
            {
                "workers": n,
                "episodes_per_s": round(episodes / timing["episodes_s"], 4),
                "episodes_s": round(timing["episodes_s"], 2),
                "startup_s": round(timing["startup_s"], 2),
                "wall_s": round(time.perf_counter() - begin, 2),
                "mean_reward": round(sum(r["total_reward"] for r in rows) / len(rows), 4),
                "actions": sum(r["actions"] for r in rows),
            }
        )
    base = runs[0]["episodes_per_s"]
    for run in runs:
        run["speedup"] = round(run["episodes_per_s"] / base, 2)
    return {"task": task, "mode": mode, "episodes": episodes, "camera_scale": camera_scale, "runs": runs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--mode", default="val", choices=["train", "val", "test"])
    parser.add_argument("--episodes", type=int, default=8, help="episodes per worker count")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to time")
    parser.add_argument("--camera-scale", type=float, default=0.5)
    parser.add_argument("--oracle", action="store_true", help="the scripted expert instead of an agent")
    parser.add_argument("--checkpoint", help="a trained agent's checkpoint instead of the random tiny agent")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--progress", action="store_true")
    args = parser.parse_args()
    try:
        if args.episodes < 1:
            raise UserError(f"--episodes must be >= 1, got {args.episodes}")
        from cliport import tasks

        tasks.make(args.task, args.mode)
        policy = "oracle" if args.oracle else _agent(args.checkpoint, args.device)
        result = bench(args.task, args.mode, args.episodes, args.workers, args.camera_scale, policy, args.progress)
    except (UserError, KeyError) as e:
        sys.exit(f"error: {e.args[0] if e.args else e}")
    result["policy"] = "oracle" if args.oracle else (args.checkpoint or "random tiny transporter_only")
    result["environment"] = measurement_environment()
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
