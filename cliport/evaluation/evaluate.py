"""Run an agent on a task's val/test seeds and summarise its success (mean total reward x100)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cliport.data.seeds import episode_seeds
from cliport.env.environment import EnvConfig
from cliport.evaluation.engine import DEFAULT_STEP_TIMEOUT, EvalEngine, resolve_workers


@dataclass
class EvalConfig:
    """Settings of ``cliport-eval``; defaults in ``configs/eval.toml``.

    Args:
        mode: split of the episodes: val or test.
        n_episodes: episodes per task (the first seeds of the split).
        checkpoint: best (by validation success), last, a step number, or all.
        device: auto (CUDA when available), cpu, cuda, ...
        camera_scale: camera resolution of the episodes; unset = the run's (what its demos were rendered at).
        video_fps: frames per second of the --video GIFs.
        workers: simulator processes stepping episodes in parallel (the agent acts on all of them in one
            batch in the main process); unset = the usable CPU cores, at most 8 and at most n_episodes.
        renderer: auto, egl or cpu (TinyRenderer); unset = the run's setting. Its pixels differ from the
            other renderer's, so evaluate with the renderer the run's demos and validation used.
    """

    mode: str
    n_episodes: int
    checkpoint: str
    device: str
    video_fps: int
    camera_scale: float | None = None
    workers: int | None = None
    renderer: str | None = None


def confidence_interval(scores: list[float]) -> tuple[float, float]:
    """95% normal-approximation interval of the mean of ``scores`` (each in [0, 100]), clipped to [0, 100]."""
    mean = statistics.mean(scores)
    if len(scores) < 2:
        return mean, mean
    half = 1.96 * statistics.stdev(scores) / math.sqrt(len(scores))
    return max(mean - half, 0.0), min(mean + half, 100.0)


def success_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a success rate, in percent; unlike the normal approximation it
    does not collapse to a point when every episode succeeds (100/100 gives [96.3, 100])."""
    rate = successes / n
    denom = 1 + z * z / n
    centre = (rate + z * z / (2 * n)) / denom
    half = z * math.sqrt(rate * (1 - rate) / n + z * z / (4 * n * n)) / denom
    return 100 * max(centre - half, 0.0), 100 * min(centre + half, 1.0)


def agent_policy(
    agent: Any,
    lang: str | None = None,
    on_act: Callable[[dict[str, Any], dict[str, Any], str | None], None] | None = None,
) -> Callable[[dict[str, Any], dict[str, Any]], dict[str, Any]]:
    """Policy calling ``agent.act`` with the task's current instruction (or ``lang`` when given)."""

    def act(obs: dict[str, Any], info: dict[str, Any]) -> dict[str, Any]:
        instruction = lang if lang is not None else info.get("lang_goal")
        result = agent.act(obs, instruction)
        if on_act is not None:
            on_act(obs, result, instruction)
        return result

    return act


def summarise(task_name: str, mode: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The evaluation result of per-episode ``rows`` (``seed``, ``total_reward``, ``actions``[, ``instruction``:
    an agent's episode's first, ``video``]):
    mean score with its 95% interval, success rate with its Wilson interval, and the rows."""
    episodes = []
    for r in rows:
        row = {"seed": r["seed"], "total_reward": round(r["total_reward"], 4), "actions": r["actions"]}
        for key in ("instruction", "video"):
            if key in r:
                row[key] = r[key]
        episodes.append(row)
    scores = [100 * e["total_reward"] for e in episodes]
    low, high = confidence_interval(scores)
    successes = sum(e["total_reward"] > 0.99 for e in episodes)
    success_low, success_high = success_interval(successes, len(episodes))
    return {
        "task": task_name,
        "mode": mode,
        "n_episodes": len(episodes),
        "mean_score": round(statistics.mean(scores), 2),
        "ci95": [round(low, 2), round(high, 2)],
        "success_rate": successes / len(episodes),
        "success_ci95": [round(success_low, 2), round(success_high, 2)],
        "episodes": episodes,
    }


def evaluate(
    agent: Any,
    task_name: str,
    mode: str,
    n_episodes: int,
    camera_scale: float = 1.0,
    progress: bool = True,
    video_dir: str | None = None,
    video_fps: int = 20,
    workers: int | None = None,
    engine: EvalEngine | None = None,
    renderer: str | None = None,
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
) -> dict[str, Any]:
    """Episodes on the first ``n_episodes`` seeds of ``mode``; returns per-episode and summary scores, the
    worker count and the renderer the episodes used ("egl" or "tiny").

    The episodes run in ``workers`` simulator processes (None: one per usable core, see
    :func:`~cliport.evaluation.engine.resolve_workers`) rendering with ``renderer`` (the workcell setting; None:
    ``configs/env.toml``'s) and killed as hung after ``step_timeout`` seconds without an answer, with
    ``agent.act_batch`` in this process, or in ``engine`` when given (its task, mode, workcell and timeout are
    then used, and ``camera_scale``, ``workers``, ``renderer`` and ``step_timeout`` ignored).
    """
    seeds = episode_seeds(mode, n_episodes)
    if engine is not None:
        rows = engine.run(agent, seeds, video_dir, video_fps)
        n_workers, used = engine.n_workers, engine.renderer
    else:
        n_workers = resolve_workers(workers, n_episodes)
        config = EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer)
        with EvalEngine(task_name, mode, config, n_workers, progress, step_timeout=step_timeout) as own:
            rows = own.run(agent, seeds, video_dir, video_fps)
            used = own.renderer
    return {**summarise(task_name, mode, rows), "workers": n_workers, "renderer": used}
