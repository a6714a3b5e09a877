"""The evaluation engine: episodes of one task stepped in N simulator processes, acted on in batches.

Every evaluation (``cliport-eval``, checkpoint validation, the study, ``scripts/oracle_check.py``) runs
its episodes here. Each worker process owns one :class:`~cliport.env.environment.Environment` with the
task and steps one episode at a time. An agent stays in the calling process on its device: whenever
episodes wait for an action, their observations go to one ``agent.act_batch(...)`` call, so memory on
the agent's device does not grow with the number of workers. The scripted oracle needs the simulator's
state, so with ``ORACLE`` the workers run whole episodes themselves.

Workers are started with the spawn context and never import torch; they get only picklable settings
(task name, mode, workcell config) and send back numpy observations, the instruction and per-episode
results. A worker that dies, or that does not answer within the step timeout (a hung simulator), is
reported with its seed, killed, replaced, and its episode re-run from the start. Closing stops every
worker within about :data:`SHUTDOWN_GRACE` + 3 seconds in all, whatever state they are in. Only with
``step_timeout=None`` and one worker does the simulator run in the calling process (nothing could stop
it there). Results come back in seed order, and on a CPU the same seeds give the same results whatever
the number of workers (on a GPU see docs/training-gpu.md: an action can depend on how many observations shared
its ``act_batch`` call).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any

from tqdm import tqdm

from cliport.env.environment import EnvConfig
from cliport.errors import ConfigError
from cliport.evaluation.stepper import CRASH_ENV, HANG_ENV, EpisodeStepper, worker_main

log = logging.getLogger(__name__)

#: Pass as the policy to run the task's scripted expert inside the workers.
ORACLE = "oracle"
#: Default worker count: the usable cores, at most this many.
MAX_DEFAULT_WORKERS = 8
#: A seed whose worker dies this many times is a bug, not bad luck: the engine stops.
MAX_CRASHES_PER_SEED = 3
#: Seconds a worker may take to answer one message (start an episode, or do one action) before it is
#: killed as hung; an oracle episode, played whole in the worker, gets this for each action it may take.
DEFAULT_STEP_TIMEOUT = 300.0
#: Seconds a worker may take to build its environment and say it is ready.
STARTUP_TIMEOUT = 300.0
#: Seconds close() waits for all workers together to stop by themselves before terminating them (a healthy
#: one stops in about 0.1 s).
SHUTDOWN_GRACE = 3.0
#: The longest the main process blocks in one wait: a Ctrl-C that lands just before a blocking call
#: is only seen when the call returns, so no wait is left unbounded.
POLL_SECONDS = 1.0


class WorkerError(RuntimeError):
    """A worker raised an exception (not a crash): the worker's traceback is the message."""


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


# ---------------------------------------------------------------------- main side
class _Worker:
    """A simulator slot: in this process (one worker, no step timeout) or a spawned process."""

    def __init__(self, index: int, spec: tuple[str, str, EnvConfig], in_process: bool) -> None:
        self.index = index
        self.seed: int | None = None  # the episode it is playing
        self.ready = in_process
        self.info: dict[str, Any] = {}  # what it said when ready: renderer, max_steps
        self.deadline: float | None = None  # monotonic time by which it must answer, while it owes an answer
        self.stepper: EpisodeStepper | None = None
        self.replies: deque[tuple[Any, ...]] = deque()
        self.process: Any = None
        self.conn: Connection | None = None
        if in_process:
            self.stepper = EpisodeStepper(*spec)
            assert self.stepper.env.task is not None
            self.info = {"renderer": self.stepper.env.renderer_kind, "max_steps": self.stepper.env.task.max_steps}
        else:
            ctx = mp.get_context("spawn")
            self.conn, child = ctx.Pipe()
            self.process = ctx.Process(target=worker_main, args=(child, *spec), daemon=True, name=f"eval-{index}")
            self.process.start()
            child.close()

    def send(self, message: tuple[Any, ...], timeout: float | None = None) -> None:
        """Send ``message``; ``timeout``: seconds it has to answer (None: no limit)."""
        if self.stepper is not None:
            self.replies.append(self.stepper.handle(message))
            return
        assert self.conn is not None
        self.deadline = None if timeout is None else time.monotonic() + timeout
        try:
            self.conn.send(message)
        except (BrokenPipeError, ConnectionResetError):
            pass  # it died; its sentinel tells the main loop

    def request_close(self) -> None:
        """Ask the worker to stop (the first half of a parallel shutdown, see :func:`_close_all`)."""
        if self.stepper is not None:
            self.stepper.close()
            return
        assert self.conn is not None
        try:
            self.conn.send(("close",))
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass

    def kill(self) -> None:
        """Stop the process now (SIGKILL: a hung native call ignores SIGTERM)."""
        if self.process is not None and self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5)

    def close(self) -> None:
        _close_all([self])


def _close_all(workers: list[_Worker], grace: float | None = None) -> None:
    """Stop ``workers`` in parallel: ask each to close, wait up to ``grace`` seconds for all of them
    together, then SIGTERM the rest (2 s more), then SIGKILL what is left: about grace + 3 s at most."""
    grace = SHUTDOWN_GRACE if grace is None else grace
    for worker in workers:
        worker.request_close()
    remote = [w for w in workers if w.process is not None]
    for limit, stop in ((grace, None), (2.0, "terminate"), (1.0, "kill")):
        alive = [w for w in remote if w.process.is_alive()]
        if not alive:
            break
        for worker in alive if stop else ():
            getattr(worker.process, stop)()
        end = time.monotonic() + limit
        for worker in alive:
            worker.process.join(timeout=max(0.0, end - time.monotonic()))
    for worker in remote:
        if worker.process.is_alive():
            pid = worker.process.pid
            log.warning("evaluation worker %d (pid %s) did not stop even after SIGKILL", worker.index, pid)
        assert worker.conn is not None
        worker.conn.close()


Policy = Any  # an agent with act_batch(observations, instructions), or ORACLE


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
        self.env_config = env_config or EnvConfig.defaults()
        self.n_workers = workers
        self.progress = progress
        self.desc = desc or f"eval {task_name}-{mode}"
        self.step_timeout = step_timeout
        self.workers: list[_Worker] = []
        self.startup_seconds = 0.0
        self.last_timing: dict[str, float] = {}
        self.renderer: str | None = None
        self._spawned = 0

    # -------------------------------------------------------------- workers
    def _spec(self) -> tuple[str, str, EnvConfig]:
        return (self.task_name, self.mode, self.env_config)

    def _new_worker(self) -> _Worker:
        self._spawned += 1
        in_process = self.n_workers == 1 and self.step_timeout is None
        return _Worker(self._spawned - 1, self._spec(), in_process=in_process)

    def start(self) -> None:
        """Start the workers (if not yet) and wait until each has its environment."""
        if self.workers:
            return
        begin = time.perf_counter()
        self.workers = [self._new_worker() for _ in range(self.n_workers)]
        for worker in self.workers:
            if not worker.ready:
                worker.deadline = time.monotonic() + STARTUP_TIMEOUT
        try:
            while not all(w.ready for w in self.workers):
                for worker, message in self._receive([w for w in self.workers if not w.ready]):
                    if message[0] == "hung":
                        raise WorkerError(f"worker {worker.index} did not start within {STARTUP_TIMEOUT:.0f} s")
                    if message[0] != "ready":
                        raise WorkerError(f"worker {worker.index} could not start: {message}")
                    self._note_ready(worker)
        except BaseException:
            self.close()
            raise
        self.startup_seconds = time.perf_counter() - begin
        for worker in self.workers:
            self._note_ready(worker)

    def _note_ready(self, worker: _Worker) -> None:
        renderer = worker.info.get("renderer")
        if self.renderer is None:
            self.renderer = renderer
        elif renderer != self.renderer:
            others = self.renderer
            log.warning("evaluation worker %d renders with %s, the others with %s", worker.index, renderer, others)

    def close(self) -> None:
        """Stop every worker (in parallel; within about SHUTDOWN_GRACE + 3 seconds)."""
        workers, self.workers = self.workers, []
        _close_all(workers)

    def __enter__(self) -> EvalEngine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _receive(self, workers: list[_Worker]) -> list[tuple[_Worker, tuple[Any, ...]]]:
        """Wait (at most POLL_SECONDS) for messages from ``workers``; a dead worker yields ``("died", exitcode)``
        and one past its deadline is killed and yields ``("hung", seconds waited)``. Possibly empty."""
        local = [(w, w.replies.popleft()) for w in workers if w.stepper is not None and w.replies]
        if local or all(w.stepper is not None for w in workers):
            return local
        remote = [w for w in workers if w.stepper is None]
        by_object: dict[Any, _Worker] = {}
        for w in remote:
            by_object[w.conn] = w
            by_object[w.process.sentinel] = w
        deadlines = [w.deadline for w in remote if w.deadline is not None]
        timeout = POLL_SECONDS if not deadlines else min(POLL_SECONDS, max(0.0, min(deadlines) - time.monotonic()))
        out: list[tuple[_Worker, tuple[Any, ...]]] = []
        seen: set[int] = set()
        for obj in wait(list(by_object), timeout=timeout):
            worker = by_object[obj]
            if worker.index in seen:
                continue
            seen.add(worker.index)
            assert worker.conn is not None
            try:
                while worker.conn.poll():
                    message = worker.conn.recv()
                    worker.deadline = None
                    if message[0] == "ready":
                        worker.ready = True
                        worker.info = message[1]
                    out.append((worker, message))
                    if message[0] in ("result", "error"):
                        break
                else:
                    if not worker.process.is_alive():
                        worker.process.join()
                        out.append((worker, ("died", worker.process.exitcode)))
            except (EOFError, OSError):
                worker.process.join(timeout=5)
                out.append((worker, ("died", worker.process.exitcode)))
        now = time.monotonic()
        for worker in remote:
            if worker.index not in seen and worker.deadline is not None and now > worker.deadline:
                worker.kill()
                out.append((worker, ("hung", None)))
        return out

    def _timeout(self, oracle: bool, worker: _Worker) -> float | None:
        if self.step_timeout is None:
            return None
        return self.step_timeout * (worker.info.get("max_steps", 1) if oracle else 1)

    # -------------------------------------------------------------- episodes
    def run(
        self,
        policy: Policy,
        seeds: Sequence[int],
        video_dir: str | None = None,
        video_fps: int = 20,
        on_result: Callable[[dict[str, Any]], None] | None = None,
    ) -> list[dict[str, Any]]:
        """Play one episode per seed with ``policy`` (an agent, or :data:`ORACLE`); rows in seed order.

        ``on_result`` hears of every finished episode as it finishes (in finishing order).
        """
        oracle = isinstance(policy, str)
        if oracle and policy != ORACLE:
            raise ValueError(f"policy must be an agent or {ORACLE!r}, got {policy!r}")
        if len(set(seeds)) != len(seeds):
            raise ValueError("seeds must be distinct")
        self.start()
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
                        message = ("start", worker.seed, oracle, video_path(worker.seed), video_fps)
                        worker.send(message, self._timeout(oracle, worker))
                busy = [w for w in self.workers if w.seed is not None or not w.ready]
                waiting: list[tuple[_Worker, int, dict[str, Any], str | None]] = []
                for worker, message in self._receive(busy):
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
                        self._note_ready(worker)
                    elif kind in ("died", "hung"):
                        self._replace(worker, kind, message[1], todo, crashes, oracle)
                        waiting = [w for w in waiting if w[0] is not worker]
                    elif kind == "error":
                        raise WorkerError(f"worker {worker.index} failed on seed {worker.seed}:\n{message[1]}")
                if waiting:
                    actions = policy.act_batch([w[2] for w in waiting], [w[3] for w in waiting])
                    for (worker, _, _, _), action in zip(waiting, actions, strict=True):
                        worker.send(("action", _executable(action)), self._timeout(False, worker))
        except BaseException:
            self.close()  # a worker may be mid-episode: start afresh next time
            raise
        finally:
            bar.close()
        self.last_timing = {
            "startup_s": self.startup_seconds,
            "episodes_s": last_end - (first_start or last_end),
        }
        return [results[s] for s in seeds]

    def _replace(
        self,
        worker: _Worker,
        kind: str,
        exitcode: int | None,
        todo: deque[int],
        crashes: dict[int, int],
        oracle: bool,
    ) -> None:
        """Report a dead or hung worker, start another in its place and put its episode back in front of the
        queue."""
        seed = worker.seed
        position = self.workers.index(worker)
        worker.kill()
        worker.close()
        what = "died" if kind == "died" else "hung"
        if seed is None:
            raise WorkerError(f"an evaluation worker of {self.task_name} {what} while starting (exit code {exitcode})")
        crashes[seed] = crashes.get(seed, 0) + 1
        if crashes[seed] >= MAX_CRASHES_PER_SEED:
            raise WorkerError(f"the simulator {what} {crashes[seed]} times on seed {seed} of {self.task_name}")
        if kind == "died":
            reason = f"died (exit code {exitcode})"
        else:
            reason = f"did not answer within {self._timeout(oracle, worker):.0f} s (hung) and was killed"
        log.warning(
            "evaluation worker %d %s during seed %d of %s-%s; re-running the seed from the start in a new worker",
            worker.index, reason, seed, self.task_name, self.mode,
        )  # fmt: skip
        todo.appendleft(seed)
        self.workers[position] = self._new_worker()
        self.workers[position].deadline = time.monotonic() + STARTUP_TIMEOUT


def _executable(action: dict[str, Any] | None) -> dict[str, Any] | None:
    """Only the poses of an agent's action travel to the simulator (not its heatmaps)."""
    if action is None:
        return None
    return {"pose0": action["pose0"], "pose1": action["pose1"]}


__all__ = [
    "CRASH_ENV",
    "DEFAULT_STEP_TIMEOUT",
    "HANG_ENV",
    "MAX_CRASHES_PER_SEED",
    "ORACLE",
    "EpisodeStepper",
    "EvalEngine",
    "WorkerError",
    "resolve_workers",
    "usable_cores",
]
