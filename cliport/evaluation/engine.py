"""The evaluation engine: episodes of one task stepped in N simulator processes, acted on in batches.

Every evaluation (``cliport-eval``, checkpoint validation, the study, ``scripts/oracle_check.py``) runs
its episodes here. Each worker process owns one :class:`~cliport.env.environment.Environment` with the
task and steps one episode at a time. An agent stays in the calling process on its device: whenever
episodes wait for an action, their observations go to one ``agent.act_batch(...)`` call, so memory on
the agent's device does not grow with the number of workers. The scripted oracle needs the simulator's
state, so with ``ORACLE`` the workers run whole episodes themselves.

Workers are started with the spawn context and never import torch; they get only picklable settings
(task name, mode, workcell config) and send back numpy observations, the instruction and per-episode
results. A worker that dies is reported (with its seed), replaced, and its episode re-run from the
start. With one worker everything runs in the calling process. Results come back in seed order, and
the same seeds give the same results whatever the number of workers.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any

from tqdm import tqdm

from cliport.env.environment import EnvConfig, Environment
from cliport.errors import ConfigError

log = logging.getLogger(__name__)

#: Pass as the policy to run the task's scripted expert inside the workers.
ORACLE = "oracle"
#: Default worker count: the usable cores, at most this many.
MAX_DEFAULT_WORKERS = 8
#: A seed whose worker dies this many times is a bug, not bad luck: the engine stops.
MAX_CRASHES_PER_SEED = 3
#: Test hook: "SEED:PATH" makes a worker process die (os._exit) after the first action of SEED (after the
#: whole episode with the oracle) when PATH does not exist yet; it creates PATH first, so the re-run succeeds.
CRASH_ENV = "CLIPORT_TEST_WORKER_CRASH"


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


# ---------------------------------------------------------------------- simulator side
@dataclass
class _Episode:
    seed: int
    oracle: bool
    video_path: str | None
    video_fps: int
    total_reward: float = 0.0
    actions: int = 0
    start: float = field(default_factory=time.perf_counter)


class EpisodeStepper:
    """One environment with the task; plays episodes one message at a time (see :meth:`handle`).

    Messages: ``("start", seed, oracle, video_path, video_fps)`` and ``("action", action)``; replies:
    ``("act", seed, observation, lang_goal)`` (an action is wanted) or ``("result", row)`` (the episode
    ended). The loop is :func:`cliport.data.rollout.run_episode`'s, so results match serial runs.
    """

    def __init__(self, task_name: str, mode: str, env_config: EnvConfig, crash_hook: bool = False) -> None:
        from cliport import tasks

        self.env = Environment(env_config, task=tasks.make(task_name, mode))
        self.crash_hook = crash_hook
        self.episode: _Episode | None = None
        self.obs: dict[str, Any] | None = None
        self.lang_goal: str | None = None

    def handle(self, message: tuple[Any, ...]) -> tuple[Any, ...]:
        if message[0] == "start":
            return self.start(*message[1:])
        if message[0] == "action":
            return self.step(message[1])
        raise ValueError(f"unknown message {message[0]!r}")

    def start(self, seed: int, oracle: bool, video_path: str | None = None, video_fps: int = 20) -> tuple[Any, ...]:
        self.episode = _Episode(seed, oracle, video_path, video_fps)
        if video_path is not None:
            self.env.start_recording()
        if oracle:
            from cliport.data.rollout import oracle_policy, run_episode

            played = run_episode(self.env, seed, oracle_policy(self.env))
            self.episode.total_reward, self.episode.actions = played.total_reward, played.n_actions
            self._maybe_crash()
            return self._finish()
        self.obs = self.env.reset(seed)
        self.lang_goal = self.env.lang_goal
        return self._next()

    def step(self, action: dict[str, Any] | None) -> tuple[Any, ...]:
        episode = self.episode
        if episode is None or episode.oracle:
            raise RuntimeError("no agent episode is waiting for an action")
        if action is None:
            return self._finish()
        self.obs, reward, done, info = self.env.step(action)
        self.lang_goal = info.get("lang_goal")
        episode.total_reward += reward
        episode.actions += 1
        self._maybe_crash()
        if done:
            return self._finish()
        return self._next()

    def _next(self) -> tuple[Any, ...]:
        assert self.episode is not None and self.env.task is not None
        if self.episode.actions >= self.env.task.max_steps:
            return self._finish()
        return ("act", self.episode.seed, self.obs, self.lang_goal)

    def _finish(self) -> tuple[Any, ...]:
        episode = self.episode
        assert episode is not None
        row: dict[str, Any] = {
            "seed": episode.seed,
            "total_reward": episode.total_reward,
            "actions": episode.actions,
            "seconds": time.perf_counter() - episode.start,
        }
        if episode.video_path is not None:
            from cliport.evaluation.visualize import save_video

            save_video(episode.video_path, self.env.stop_recording(), episode.video_fps)
            row["video"] = episode.video_path
        self.episode, self.obs = None, None
        return ("result", row)

    def _maybe_crash(self) -> None:
        spec = os.environ.get(CRASH_ENV) if self.crash_hook else None
        if not spec or self.episode is None:
            return
        seed, _, path = spec.partition(":")
        if int(seed) == self.episode.seed and not os.path.exists(path):
            open(path, "w").close()
            os._exit(3)

    def close(self) -> None:
        self.env.close()


def _worker_main(conn: Connection, task_name: str, mode: str, env_config: EnvConfig) -> None:
    """A worker process: build the stepper, say ready, then answer messages until "close" or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    try:
        stepper = EpisodeStepper(task_name, mode, env_config, crash_hook=True)
    except Exception:
        conn.send(("error", traceback.format_exc()))
        return
    conn.send(("ready",))
    try:
        while True:
            try:
                message = conn.recv()
            except EOFError:
                break
            if message[0] == "close":
                break
            try:
                reply = stepper.handle(message)
            except Exception:
                reply = ("error", traceback.format_exc())
            conn.send(reply)
    finally:
        stepper.close()


# ---------------------------------------------------------------------- main side
class _Worker:
    """A simulator slot: in this process (one-worker mode) or a spawned process."""

    def __init__(self, index: int, spec: tuple[str, str, EnvConfig], in_process: bool) -> None:
        self.index = index
        self.seed: int | None = None  # the episode it is playing
        self.ready = in_process
        self.stepper: EpisodeStepper | None = None
        self.replies: deque[tuple[Any, ...]] = deque()
        self.process: Any = None
        self.conn: Connection | None = None
        if in_process:
            self.stepper = EpisodeStepper(*spec)
        else:
            ctx = mp.get_context("spawn")
            self.conn, child = ctx.Pipe()
            self.process = ctx.Process(target=_worker_main, args=(child, *spec), daemon=True, name=f"eval-{index}")
            self.process.start()
            child.close()

    def send(self, message: tuple[Any, ...]) -> None:
        if self.stepper is not None:
            self.replies.append(self.stepper.handle(message))
        else:
            assert self.conn is not None
            try:
                self.conn.send(message)
            except (BrokenPipeError, ConnectionResetError):
                pass  # it died; its sentinel tells the main loop

    def close(self) -> None:
        if self.stepper is not None:
            self.stepper.close()
            return
        assert self.conn is not None
        try:
            self.conn.send(("close",))
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass
        self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=5)
        self.conn.close()


Policy = Any  # an agent with act_batch(observations, instructions), or ORACLE


class EvalEngine:
    """Plays episodes of ``task_name`` (``mode`` split) in ``workers`` simulators; reusable across runs.

    ``run(policy, seeds)`` returns one row per seed, in seed order: ``seed``, ``total_reward``, ``actions``,
    ``seconds`` (and ``video`` when recorded). :attr:`last_timing` holds the start-up time of the workers
    and the time from the first episode's start to the last one's end. Use as a context manager (or call
    :meth:`close`) so the workers stop.
    """

    def __init__(
        self,
        task_name: str,
        mode: str,
        env_config: EnvConfig | None = None,
        workers: int = 1,
        progress: bool = True,
        desc: str | None = None,
    ) -> None:
        if workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        self.task_name, self.mode = task_name, mode
        self.env_config = env_config or EnvConfig.defaults()
        self.n_workers = workers
        self.progress = progress
        self.desc = desc or f"eval {task_name}-{mode}"
        self.workers: list[_Worker] = []
        self.startup_seconds = 0.0
        self.last_timing: dict[str, float] = {}
        self._spawned = 0

    # -------------------------------------------------------------- workers
    def _spec(self) -> tuple[str, str, EnvConfig]:
        return (self.task_name, self.mode, self.env_config)

    def _new_worker(self) -> _Worker:
        self._spawned += 1
        return _Worker(self._spawned - 1, self._spec(), in_process=self.n_workers == 1)

    def start(self) -> None:
        """Start the workers (if not yet) and wait until each has its environment."""
        if self.workers:
            return
        begin = time.perf_counter()
        self.workers = [self._new_worker() for _ in range(self.n_workers)]
        while not all(w.ready for w in self.workers):
            for worker, message in self._receive([w for w in self.workers if not w.ready]):
                if message[0] != "ready":
                    raise WorkerError(f"worker {worker.index} could not start: {message}")
        self.startup_seconds = time.perf_counter() - begin

    def close(self) -> None:
        """Stop every worker."""
        workers, self.workers = self.workers, []
        for worker in workers:
            worker.close()

    def __enter__(self) -> EvalEngine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _receive(self, workers: list[_Worker]) -> list[tuple[_Worker, tuple[Any, ...]]]:
        """Wait for messages from ``workers``; a dead worker yields ``("died", exitcode)``."""
        local = [(w, w.replies.popleft()) for w in workers if w.stepper is not None and w.replies]
        if local or all(w.stepper is not None for w in workers):
            return local
        remote = [w for w in workers if w.stepper is None]
        by_object: dict[Any, _Worker] = {}
        for w in remote:
            by_object[w.conn] = w
            by_object[w.process.sentinel] = w
        out: list[tuple[_Worker, tuple[Any, ...]]] = []
        seen: set[int] = set()
        for obj in wait(list(by_object)):
            worker = by_object[obj]
            if worker.index in seen:
                continue
            seen.add(worker.index)
            assert worker.conn is not None
            try:
                while worker.conn.poll():
                    message = worker.conn.recv()
                    if message[0] == "ready":
                        worker.ready = True
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
        return out

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
                        worker.send(("start", worker.seed, oracle, video_path(worker.seed), video_fps))
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
                    elif kind == "died":
                        self._replace(worker, message[1], todo, crashes)
                        waiting = [w for w in waiting if w[0] is not worker]
                    elif kind == "error":
                        raise WorkerError(f"worker {worker.index} failed on seed {worker.seed}:\n{message[1]}")
                if waiting:
                    actions = policy.act_batch([w[2] for w in waiting], [w[3] for w in waiting])
                    for (worker, _, _, _), action in zip(waiting, actions, strict=True):
                        worker.send(("action", _executable(action)))
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

    def _replace(self, worker: _Worker, exitcode: int | None, todo: deque[int], crashes: dict[int, int]) -> None:
        """Report a dead worker, start another in its place and put its episode back in front of the queue."""
        seed = worker.seed
        position = self.workers.index(worker)
        worker.close()
        if seed is None:
            raise WorkerError(f"an evaluation worker of {self.task_name} died while starting (exit code {exitcode})")
        crashes[seed] = crashes.get(seed, 0) + 1
        if crashes[seed] >= MAX_CRASHES_PER_SEED:
            raise WorkerError(f"the simulator died {crashes[seed]} times on seed {seed} of {self.task_name}")
        log.warning(
            "evaluation worker %d died (exit code %s) during seed %d of %s-%s; re-running the seed from the "
            "start in a new worker",
            worker.index, exitcode, seed, self.task_name, self.mode,
        )  # fmt: skip
        todo.appendleft(seed)
        self.workers[position] = self._new_worker()


def _executable(action: dict[str, Any] | None) -> dict[str, Any] | None:
    """Only the poses of an agent's action travel to the simulator (not its heatmaps)."""
    if action is None:
        return None
    return {"pose0": action["pose0"], "pose1": action["pose1"]}
