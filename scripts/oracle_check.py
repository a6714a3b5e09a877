"""Run a task's scripted oracle over seeds and print its success rate as JSON.

Usage: python scripts/oracle_check.py --task place-red-in-green --episodes 100 [--mode train] [--workers 2]
       python scripts/oracle_check.py --task towers-of-hanoi --seeds 14 28   (re-run chosen seeds)
       python scripts/oracle_check.py --task palletizing-boxes --episodes 100 --record-dir docs/oracle
       python scripts/oracle_check.py --blind --task align-rope --mode test --record-dir docs/oracle/blind
Episodes run in the evaluation engine (``cliport.evaluation.engine``): the oracle inside each worker
process, one environment per worker, the same rollout loop as demonstration generation.
Success = total reward > 0.99. A task group name (e.g. multi-ravens) prints one line per task.

With ``--blind`` the language-blind expert plays instead (``Task.blind_plan``: the oracle's skill, but goals
guessed from the scene without reading the instruction); its mean reward is the task's language-blind ceiling
(docs/results/blind-ceilings.md).

With ``--record-dir DIR`` every finished seed is appended to ``DIR/TASK.jsonl`` as one JSON line the
moment it is done, and seeds already there (same mode and camera scale) are not run again: an interrupted check
resumes where it stopped, several runs can fill one file, and the summary covers recorded and new
seeds alike. ``scripts/oracle_table.py`` turns the files under ``docs/oracle/`` into the table of docs/tasks.md.
Records do not say which code produced them beyond the version and commit: after changing a task,
start a new file (or re-run the seeds in question with ``--seeds``, which always re-runs them).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from collections.abc import Iterator

from cliport import __version__, tasks
from cliport.data.seeds import episode_seeds
from cliport.env.environment import EnvConfig
from cliport.errors import ConfigError
from cliport.evaluation.engine import BLIND, ORACLE, EvalEngine, resolve_workers
from cliport.utils.machine import measurement_environment


def _commit() -> str | None:
    """The checkout's short commit hash, "+dirty" when the code has uncommitted changes; None outside git."""
    here = os.path.dirname(os.path.abspath(__file__))
    code = ["git", "status", "--porcelain", "--untracked-files=no", "--", "cliport", "tasks", "configs", "scripts"]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True)
        dirty = subprocess.run(code, cwd=os.path.dirname(here), capture_output=True)
    except OSError:
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def iter_records(path: str) -> Iterator[dict]:
    """The JSON records of a JSON-lines file; a torn line (a run killed mid-write) is skipped."""
    with open(path) as f:
        for line in f:
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                continue


def read_records(path: str, task_name: str, mode: str, camera_scale: float, policy: str = ORACLE) -> dict[int, dict]:
    """Recorded per-seed results of one task, mode, camera scale and expert (records without a ``policy`` are
    the oracle's) in a JSON-lines file, by seed (the newest record of a seed wins; a seed on a torn line is
    simply run again)."""
    if not os.path.exists(path):
        return {}
    return {
        int(r["seed"]): r
        for r in iter_records(path)
        if r.get("task") == task_name
        and r.get("mode") == mode
        and r.get("camera_scale") == camera_scale
        and r.get("policy", ORACLE) == policy
    }


def check(
    task_name: str,
    episodes: int,
    mode: str = "train",
    camera_scale: float = 1.0,
    progress: bool = True,
    workers: int | None = 1,
    seeds: list[int] | None = None,
    record: str | None = None,
    policy: str = ORACLE,
) -> dict:
    """Statistics of ``task_name``'s scripted expert (``policy``: ``ORACLE``, or ``BLIND`` for the language-blind
    one) over the first ``episodes`` protocol seeds of ``mode`` (or ``seeds``).

    With ``record``, results are appended to that JSON-lines file as they finish and protocol seeds
    already recorded there are taken from it instead of being run (chosen ``seeds`` always run).
    The episodes run in the evaluation engine with ``workers`` simulators (None: one per usable core,
    at most one per seed to run).
    """
    chosen = seeds is not None
    seeds = seeds if seeds is not None else episode_seeds(mode, episodes)
    done: dict[int, dict] = {}
    if record is not None and not chosen:
        recorded = read_records(record, task_name, mode, camera_scale, policy)
        done = {s: recorded[s] for s in seeds if s in recorded}
    todo = [s for s in seeds if s not in done]
    sink = None
    if record is not None:
        os.makedirs(os.path.dirname(os.path.abspath(record)), exist_ok=True)
        torn = False
        if os.path.exists(record) and os.path.getsize(record) > 0:
            with open(record, "rb") as f:
                f.seek(-1, os.SEEK_END)
                torn = f.read(1) != b"\n"
        sink = open(record, "a")
        if torn:  # start our lines on a fresh one
            sink.write("\n")
    meta = {"task": task_name, "mode": mode, "camera_scale": camera_scale, "cliport_version": __version__}
    if policy != ORACLE:
        meta["policy"] = policy
    if sink is not None:
        meta["commit"] = _commit()
    unwritten = list(todo)  # records are appended in seed order, each once every earlier seed has finished

    def finished(row: dict) -> None:
        done[row["seed"]] = {
            "seed": row["seed"],
            "success": row["total_reward"] > 0.99,
            "total_reward": row["total_reward"],
            "seconds": row["seconds"],
        }
        while sink is not None and unwritten and unwritten[0] in done:
            result = done[unwritten.pop(0)]
            sink.write(json.dumps({**meta, **result, "total_reward": round(result["total_reward"], 4)}) + "\n")
            sink.flush()
            os.fsync(sink.fileno())

    try:
        if todo:
            n_workers = resolve_workers(None if workers is None else min(workers, len(todo)), len(todo))
            config = EnvConfig.defaults(camera_scale=camera_scale)
            with EvalEngine(task_name, mode, config, n_workers, progress, task_name) as engine:
                engine.run(policy, todo, on_result=finished)
    finally:
        if sink is not None:
            sink.close()
    results = [done[s] for s in seeds]
    failures = [{"seed": r["seed"], "total_reward": round(r["total_reward"], 3)} for r in results if not r["success"]]
    return {
        "task": task_name,
        "policy": policy,
        "mode": mode,
        "episodes": len(results),
        "success_rate": sum(r["success"] for r in results) / len(results),
        "mean_reward": round(statistics.mean(r["total_reward"] for r in results), 4),
        "seconds_per_episode": round(statistics.mean(r["seconds"] for r in results), 2),
        "camera_scale": camera_scale,
        "failed_seeds": failures,
        "newly_run": len(todo),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True, help="task or task group (cliport-tasks lists them)")
    parser.add_argument("--episodes", type=int, default=100, help="first N seeds of the mode's protocol")
    parser.add_argument("--seeds", type=int, nargs="+", help="run these seeds instead")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument("--camera-scale", type=float, default=1.0)
    parser.add_argument(
        "--blind", action="store_true", help="the language-blind expert instead of the oracle (its score: the ceiling)"
    )
    parser.add_argument(
        "--workers", type=int, help="worker processes (one simulator each); default: the usable cores, at most 8"
    )
    parser.add_argument(
        "--record-dir", metavar="DIR", help="append per-seed results to DIR/TASK.jsonl and skip seeds already there"
    )
    args = parser.parse_args()
    if args.episodes < 1:
        sys.exit("error: --episodes must be >= 1")
    try:
        resolve_workers(args.workers, len(args.seeds) if args.seeds else args.episodes)
    except ConfigError as e:
        sys.exit(f"error: {e}")
    try:
        names = tasks.resolve(args.task)
        tasks.make(names[0], args.mode)
    except (KeyError, ValueError) as e:
        sys.exit(f"error: {e.args[0]}")
    for name in names:
        record = None if args.record_dir is None else os.path.join(args.record_dir, f"{name}.jsonl")
        result = check(
            name,
            args.episodes,
            args.mode,
            args.camera_scale,
            workers=args.workers,
            seeds=args.seeds,
            record=record,
            policy=BLIND if args.blind else ORACLE,
        )
        print(json.dumps({**result, "environment": measurement_environment()}), flush=True)


if __name__ == "__main__":
    main()
