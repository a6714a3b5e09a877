"""The evaluation engine: episodes of one task stepped in N simulator processes, acted on in batches.

Every evaluation (``cliport-eval``, checkpoint validation, the study, ``scripts/oracle_check.py``) runs
its episodes here. Each worker process owns one :class:`~cliport.env.environment.Environment` with the
task and steps one episode at a time. An agent stays in the calling process on its device: whenever
episodes wait for an action, their observations go to one ``agent.act_batch(...)`` call, so memory on
the agent's device does not grow with the number of workers. The scripted oracle needs the simulator's
state, so with ``ORACLE`` (or ``BLIND``, the language-blind expert) the workers run whole episodes themselves.

Workers are started with the spawn context and never import torch; they get only picklable settings
(task name, mode, workcell config) and send back numpy observations, the instruction and per-episode
results. A worker that dies, or that does not answer within the step timeout (a hung simulator), is
reported with its seed, killed, replaced, and its episode re-run from the start. Closing stops every
worker within about :data:`~cliport.evaluation.workers.SHUTDOWN_GRACE` + 3 seconds in all, whatever state
they are in. Only with ``step_timeout=None`` and one worker does the simulator run in the calling process
(nothing could stop it there). Results come back in seed order, and on a CPU the same seeds give the same
results whatever the number of workers (on a GPU see docs/training-gpu.md: an action can depend on how many
observations shared its ``act_batch`` call).

This module is the evaluation loop; the processes, their deadlines, replacement and shutdown are the worker
pool's (:mod:`cliport.evaluation.workers`).
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from tqdm import tqdm

from cliport.env.environment import EnvConfig
from cliport.errors import ConfigError
from cliport.evaluation.workers import Worker, WorkerError, WorkerPool

#: Pass as the policy to run the task's scripted expert inside the workers.
ORACLE = "oracle"
#: Pass as the policy to run the task's language-blind expert (``Task.blind_plan``) inside the workers.
BLIND = "blind"
SCRIPTED = (ORACLE, BLIND)
#: Default worker count: the usable cores, at most this many.
MAX_DEFAULT_WORKERS = 8
#: Seconds a worker may take to answer one message (start an episode, or do one action) before it is
#: killed as hung; an oracle episode, played whole in the worker, gets this for each action it may take.
DEFAULT_STEP_TIMEOUT = 300.0


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def resolve_workers(workers: int | None, n_episodes: int, flag: str = "--workers") -> int:
    """The worker count to use: ``workers`` checked against ``n_episodes`` (ConfigError naming ``flag``), or,
    when None, the usable cores capped at :data:`MAX_DEFAULT_WORKERS` and at ``n_episodes``."""
    if workers is None:
        return max(1, min(usable_cores(), MAX_DEFAULT_WORKERS, n_episodes))
    if workers < 1:
        raise ConfigError(f"{flag} must be >= 1, got {workers}")
    if workers > n_episodes:
        raise ConfigError(f"{flag} {workers} is more than the {n_episodes} episode(s) to run; use at most {n_episodes}")
    return workers


Policy = Any  # an agent with act_batch(observations, instructions), ORACLE or BLIND


class EvalEngine:
    """Plays episodes of ``task_name`` (``mode`` split) in ``workers`` simulators; reusable across runs.

    ``run(policy, seeds)`` returns one row per seed, in seed order: ``seed``, ``total_reward``, ``actions``,
    ``seconds`` (and ``video`` when recorded). :attr:`last_timing` holds the start-up time of the workers
    and the time from the first episode's start to the last one's end; :attr:`renderer` the renderer the
    simulators use ("egl" or "tiny"). ``step_timeout``: seconds a worker may take per episode start or
    action before it is killed as hung and its episode re-run (None: no limit, and with one worker the
    simulator runs in this process). Use as a context manager (or call :meth:`close`) so the workers stop.
    """

    def __init__(
        self,
        task_name: str,
        mode: str,
        env_config: EnvConfig | None = None,
        workers: int = 1,
        progress: bool = True,
        desc: str | None = None,
        step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
    ) -> None:
        if workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        if step_timeout is not None and step_timeout <= 0:
            raise ConfigError(f"step_timeout must be > 0 seconds, got {step_timeout}")
        self.task_name, self.mode = task_name, mode
        self.pool = WorkerPool(task_name, mode, env_config or EnvConfig.defaults(), workers, step_timeout)
        self.progress = progress
        self.desc = desc or f"eval {task_name}-{mode}"
        self.last_timing: dict[str, float] = {}

    # -------------------------------------------------------------- the pool
    @property
    def n_workers(self) -> int:
        return self.pool.n_workers

    @property
    def workers(self) -> list[Worker]:
        return self.pool.workers

    @property
    def renderer(self) -> str | None:
        return self.pool.renderer

    def start(self) -> None:
        """Start the workers (if not yet) and wait until each has its environment."""
        self.pool.start()

    def close(self) -> None:
        """Stop every worker (in parallel; within about SHUTDOWN_GRACE + 3 seconds)."""
        self.pool.close()

    def __enter__(self) -> EvalEngine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -------------------------------------------------------------- episodes
    def run(
        self,
        policy: Policy,
        seeds: Sequence[int],
        video_dir: str | None = None,
        video_fps: int = 20,
        on_result: Callable[[dict[str, Any]], None] | None = None,
    ) -> list[dict[str, Any]]:
        """Play one episode per seed with ``policy`` (an agent, :data:`ORACLE` or :data:`BLIND`); rows in seed order.

        ``on_result`` hears of every finished episode as it finishes (in finishing order).
        """
        oracle = isinstance(policy, str)
        if oracle and policy not in SCRIPTED:
            raise ValueError(f"policy must be an agent, {ORACLE!r} or {BLIND!r}, got {policy!r}")
        scripted = policy if oracle else ""
        if len(set(seeds)) != len(seeds):
            raise ValueError("seeds must be distinct")
        self.start()
        pool = self.pool
        todo: deque[int] = deque(seeds)
        results: dict[int, dict[str, Any]] = {}
        crashes: dict[int, int] = {}
        first_start: float | None = None
        last_end = time.perf_counter()
        bar = tqdm(total=len(seeds), desc=self.desc, unit="ep", disable=not self.progress, leave=False)

        def video_path(seed: int) -> str | None:
            if video_dir is None:
                return None
            return os.path.join(video_dir, f"{self.task_name}-{self.mode}-{seed:06d}.gif")

        try:
            while len(results) < len(seeds):
                for worker in self.workers:
                    if worker.ready and worker.seed is None and todo:
                        worker.seed = todo.popleft()
                        first_start = first_start or time.perf_counter()
                        start_message = ("start", worker.seed, scripted, video_path(worker.seed), video_fps)
                        worker.send(start_message, pool.timeout(oracle, worker))
                busy = [w for w in self.workers if w.seed is not None or not w.ready]
                waiting: list[tuple[Worker, int, dict[str, Any], str | None]] = []
                for worker, message in pool.receive(busy):
                    kind = message[0]
                    if kind == "act":
                        waiting.append((worker, message[1], message[2], message[3]))
                    elif kind == "result":
                        row = message[1]
                        results[row["seed"]] = row
                        worker.seed = None
                        last_end = time.perf_counter()
                        bar.update(1)
                        if on_result is not None:
                            on_result(row)
                    elif kind == "ready":
                        pool.note_ready(worker)
                    elif kind in ("died", "hung"):
                        todo.appendleft(pool.replace(worker, kind, message[1], crashes, oracle))
                        waiting = [w for w in waiting if w[0] is not worker]
                    elif kind == "error":
                        raise WorkerError(f"worker {worker.index} failed on seed {worker.seed}:\n{message[1]}")
                if waiting:
                    actions = policy.act_batch([w[2] for w in waiting], [w[3] for w in waiting])
                    for (worker, _, _, _), action in zip(waiting, actions, strict=True):
                        worker.send(("action", _executable(action)), pool.timeout(False, worker))
        except BaseException:
            self.close()  # a worker may be mid-episode: start afresh next time
            raise
        finally:
            bar.close()
        self.last_timing = {
            "startup_s": pool.startup_seconds,
            "episodes_s": last_end - (first_start or last_end),
        }
        return [results[s] for s in seeds]


def _executable(action: dict[str, Any] | None) -> dict[str, Any] | None:
    """Only the poses of an agent's action travel to the simulator (not its heatmaps)."""
    if action is None:
        return None
    return {"pose0": action["pose0"], "pose1": action["pose1"]}


__all__ = ["BLIND", "DEFAULT_STEP_TIMEOUT", "ORACLE", "EvalEngine", "WorkerError", "resolve_workers", "usable_cores"]
