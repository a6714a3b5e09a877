"""Demonstration generation: run a task's oracle over the seed protocol in parallel, save successes.

Episodes land in ``DATA_DIR/<task>-<mode>/<seed:06d>.npz``. The dataset of N episodes is the first
N seeds (in protocol order) whose oracle episode succeeds; failed seeds are skipped and recorded.
Re-running the same command resumes: finished episodes are kept and known failures not retried.
With ``shard=(i, k)`` this process takes every k-th seed starting at index i and aims for its share
of N, so k machines can fill one shared folder.
"""

from __future__ import annotations

import concurrent.futures as cf
import glob
import json
import multiprocessing as mp
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from tqdm import tqdm

from cliport import __version__
from cliport.data.episode_io import dataset_dir, episode_path, existing_seeds, read_meta, save_episode
from cliport.data.seeds import episode_seeds
from cliport.errors import ConfigError, UserError
from cliport.utils.config import defaults as config_defaults
from cliport.utils.files import write_json


@dataclass
class DemoConfig:
    """Demonstration generation settings; defaults in ``configs/demos.toml``.

    Args:
        data_dir: folder that holds one ``<task>-<mode>`` folder of episode files per task and split.
        workers: parallel simulator processes.
        camera_scale: camera resolution factor of the rendered observations (1.0 = 640 x 480, as the
            reference; 0.5 is faster); recorded in every episode and checked against validation's.
        raw_images: also store the three raw camera images per step (~1 MB per step even compressed).
        max_failures: give up when the oracle fails on more than this many seeds in one run.
        every_instruction: also record, for every step, the task's other instructions of that scene with the
            oracle's action for each (tasks with ``offers_instruction_variants``; ``cliport-train
            --every-instruction`` trains on them all).
    """

    data_dir: str
    workers: int
    camera_scale: float
    raw_images: bool
    max_failures: int
    every_instruction: bool

    @classmethod
    def defaults(cls, **overrides: Any) -> DemoConfig:
        """The TOML defaults with the keyword overrides that are not None."""
        return config_defaults(cls, "demos", **overrides)


class GenerationError(UserError, RuntimeError):
    """Demonstration generation cannot go on (e.g. the oracle keeps failing)."""


# ---------------------------------------------------------------------- worker side
_ENV = None
_VARIANTS = False  # record every instruction of each scene (DemoConfig.every_instruction)


def init_worker(
    task_name: str, mode: str, camera_scale: float, raw_images: bool = False, every_instruction: bool = False
) -> None:
    """Give this process its environment with the task (one PyBullet client per process)."""
    global _ENV, _VARIANTS
    _VARIANTS = every_instruction
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    _ENV = Environment(
        EnvConfig.defaults(camera_scale=camera_scale, raw_images=raw_images), task=tasks.make(task_name, mode)
    )


def check_seed(seed: int) -> dict[str, Any]:
    """Run the oracle on ``seed`` in this worker's environment (see :func:`init_worker`) without saving."""
    from cliport.data.rollout import oracle_policy, run_episode

    assert _ENV is not None, "init_worker was not called in this process"
    episode = run_episode(_ENV, seed, oracle_policy(_ENV))
    return {"seed": seed, "success": episode.success, "total_reward": episode.total_reward, "seconds": episode.seconds}


def _worker_run(seed: int, path: str, meta: dict[str, Any], raw_images: bool) -> dict[str, Any]:
    from cliport.data.rollout import oracle_policy, run_episode

    assert _ENV is not None
    episode = run_episode(_ENV, seed, oracle_policy(_ENV), record=True, variants=_VARIANTS)
    result = {
        "seed": seed,
        "success": episode.success,
        "total_reward": episode.total_reward,
        "steps": episode.n_actions,
        "renderer": _ENV.renderer_kind,
    }
    if episode.success:
        meta = {**meta, "seed": seed, "total_reward": episode.total_reward, "n_steps": episode.n_actions}
        meta["renderer"] = _ENV.renderer_kind  # what rendered these pixels ("egl" or "tiny")
        result["bytes"] = save_episode(path, episode.steps, meta, raw_images=raw_images)
    return result


# ---------------------------------------------------------------------- driver
def generate(
    task: str,
    mode: str,
    n: int,
    config: DemoConfig | None = None,
    shard: tuple[int, int] = (0, 1),
    progress: bool = True,
) -> dict[str, Any]:
    """Generate ``n`` successful oracle episodes (this shard's share of them); returns the summary."""
    global _ENV
    from cliport import tasks

    config = config or DemoConfig.defaults()
    if not tasks.make(task, mode).offers_instruction_variants and config.every_instruction:  # fails fast on a bad name
        raise ConfigError(
            f"{task} builds each scene for one instruction, so every_instruction has nothing to record "
            f"(tasks that offer it: {', '.join(tasks.with_instruction_variants())})"
        )
    index, count = shard
    if not (count >= 1 and 0 <= index < count):
        raise ConfigError(f"shard must be I/K with 0 <= I < K, got {index}/{count}")
    if n < 0:
        raise ConfigError(f"n must be >= 0, got {n}")
    if config.workers < 1:
        raise ConfigError(f"workers must be >= 1, got {config.workers}")
    target = n // count + (1 if index < n % count else 0)
    folder = dataset_dir(config.data_dir, task, mode)
    os.makedirs(folder, exist_ok=True)
    for stale in glob.glob(os.path.join(folder, "*.tmp-*")):
        os.remove(stale)
    suffix = "" if count == 1 else f"-shard{index}of{count}"
    failures_path = os.path.join(folder, f"failed_seeds{suffix}.json")
    known_failures: dict[int, float] = {}
    if os.path.exists(failures_path):
        with open(failures_path) as f:
            known_failures = {int(k): v for k, v in json.load(f).items()}

    # A truncated or foreign episode file (an interrupted copy, a full disk) is deleted and its seed
    # generated again; check_episode_file says which damage this cheap check cannot see.
    import logging

    from cliport.data.episode_io import EpisodeFileError, check_episode_file

    done: set[int] = set()
    removed_bad: set[int] = set()
    one_instruction: list[int] = []
    for seed in existing_seeds(folder):
        try:
            check_episode_file(episode_path(folder, seed))
        except EpisodeFileError as err:
            logging.getLogger(__name__).warning("%s; deleting it to generate it again", err)
            os.remove(episode_path(folder, seed))
            removed_bad.add(seed)
        else:
            if config.every_instruction and not read_meta(episode_path(folder, seed)).get("every_instruction"):
                os.remove(episode_path(folder, seed))
                one_instruction.append(seed)
                continue
            done.add(seed)
    if one_instruction:
        logging.getLogger(__name__).warning(
            "%d episode files in %s recorded one instruction per step: generating them again with every instruction",
            len(one_instruction),
            folder,
        )
    meta = {"task": task, "mode": mode, "cliport_version": __version__, "camera_scale": config.camera_scale}
    if config.every_instruction:
        meta["every_instruction"] = True

    def seed_stream() -> Iterator[int]:
        i = index
        while True:
            yield episode_seeds(mode, 1, i)[0]
            i += count

    stream = seed_stream()
    saved_before = 0
    new_failures: dict[int, float] = {}
    n_saved, n_bytes, n_steps, n_regenerated = 0, 0, 0, 0
    start = time.perf_counter()
    bar = tqdm(total=target, desc=f"{task}-{mode}", disable=not progress, unit="demo")

    def next_seed() -> int | None:
        nonlocal saved_before
        for seed in stream:
            if seed in done:
                saved_before += 1
                bar.update(1)
                if saved_before + n_saved >= target:
                    return None
                continue
            if seed in known_failures:
                continue
            return seed
        return None

    renderers: set[str] = set()  # what this run's episodes were rendered with

    def record(result: dict[str, Any]) -> None:
        nonlocal n_saved, n_bytes, n_steps, n_regenerated
        renderers.add(result["renderer"])
        if result["success"]:
            n_saved += 1
            if result["seed"] in removed_bad:
                n_regenerated += 1
            n_bytes += result["bytes"]
            n_steps += result["steps"]
            bar.update(1)
        else:
            new_failures[result["seed"]] = round(result["total_reward"], 4)
            write_json(failures_path, {str(k): v for k, v in sorted({**known_failures, **new_failures}.items())})
            if len(new_failures) > config.max_failures:
                raise GenerationError(
                    f"the {task} oracle failed on {len(new_failures)} seeds in this run (limit max_failures="
                    f"{config.max_failures}); see {failures_path}"
                )

    init_args = (task, mode, config.camera_scale, config.raw_images, config.every_instruction)
    try:
        if target > 0 and config.workers == 1:
            while saved_before + n_saved < target and (next_one := next_seed()) is not None:
                if _ENV is None:  # a complete folder starts no simulator
                    init_worker(*init_args)
                record(_worker_run(next_one, episode_path(folder, next_one), meta, config.raw_images))
        elif target > 0:
            ctx = mp.get_context("spawn")
            with cf.ProcessPoolExecutor(
                config.workers, mp_context=ctx, initializer=init_worker, initargs=init_args
            ) as pool:
                pending: set[cf.Future] = set()
                exhausted = False
                while True:
                    while (
                        not exhausted
                        and saved_before + n_saved + len(pending) < target
                        and len(pending) < config.workers
                    ):
                        next_one = next_seed()
                        if next_one is None:
                            exhausted = True
                            break
                        pending.add(
                            pool.submit(_worker_run, next_one, episode_path(folder, next_one), meta, config.raw_images)
                        )
                    if not pending:
                        break
                    # Bounded: a Ctrl-C landing just before an unbounded wait would only be seen when a
                    # demo finishes (up to a minute for the pile tasks).
                    finished, pending = cf.wait(pending, timeout=1.0, return_when=cf.FIRST_COMPLETED)
                    for future in finished:
                        record(future.result())
    finally:
        bar.close()
        if _ENV is not None:
            _ENV.close()
            _ENV = None
    seconds = time.perf_counter() - start
    summary = {
        "task": task,
        "mode": mode,
        "shard": f"{index}/{count}",
        "target": target,
        "saved": n_saved,
        "skipped_existing": saved_before,
        "corrupt_removed": sorted(removed_bad),
        "regenerated": n_regenerated,
        "total_in_folder": len(existing_seeds(folder)),
        "failed_seeds": sorted(new_failures),
        "known_failed_seeds_skipped": len(known_failures),
        "seconds": round(seconds, 1),
        "demos_per_minute": round(n_saved / seconds * 60, 2) if n_saved else 0.0,
        "mb_per_step": round(n_bytes / n_steps / 1e6, 4) if n_steps else None,
        "workers": config.workers,
        "camera_scale": config.camera_scale,
        "every_instruction": config.every_instruction,
        "renderer": ",".join(sorted(renderers)) or None,
        "cliport_version": __version__,
    }
    write_json(os.path.join(folder, f"summary{suffix}.json"), summary)
    return summary
