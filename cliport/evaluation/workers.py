"""The evaluation engine's worker pool: N simulator processes of one task and split, started, watched for
deaths and missed deadlines, replaced, and stopped.

Each worker is a spawned process running :func:`~cliport.evaluation.stepper.worker_main` (or, with one
worker and no step timeout, an :class:`~cliport.evaluation.stepper.EpisodeStepper` in this process). The
pool only moves messages and keeps time; what the messages mean is the engine's
(:class:`~cliport.evaluation.engine.EvalEngine`).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import time
from collections import deque
from multiprocessing.connection import Connection, wait
from typing import Any

from cliport.env.environment import EnvConfig
from cliport.evaluation.stepper import EpisodeStepper, worker_main

log = logging.getLogger(__name__)

#: A seed whose worker dies this many times is a bug, not bad luck: the engine stops.
MAX_CRASHES_PER_SEED = 3
#: Seconds a worker may take to build its environment and say it is ready.
STARTUP_TIMEOUT = 300.0
#: Seconds close() waits for all workers together to stop by themselves before terminating them (a healthy
#: one stops in about 0.1 s).
SHUTDOWN_GRACE = 3.0
#: The longest the main process blocks in one wait: a Ctrl-C that lands just before a blocking call
#: is only seen when the call returns, so no wait is left unbounded.
POLL_SECONDS = 1.0

Message = tuple[Any, ...]


class WorkerError(RuntimeError):
    """A worker raised an exception (not a crash): the worker's traceback is the message."""


class Worker:
    """A simulator slot: in this process (one worker, no step timeout) or a spawned process."""

    def __init__(self, index: int, spec: tuple[str, str, EnvConfig], in_process: bool) -> None:
        self.index = index
        self.seed: int | None = None  # the episode it is playing
        self.ready = in_process
        self.info: dict[str, Any] = {}  # what it said when ready: renderer, max_steps
        self.deadline: float | None = None  # monotonic time by which it must answer, while it owes an answer
        self.stepper: EpisodeStepper | None = None
        self.replies: deque[Message] = deque()
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

    def send(self, message: Message, timeout: float | None = None) -> None:
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
        """Ask the worker to stop (the first half of a parallel shutdown, see :func:`close_all`)."""
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
        close_all([self])


def close_all(workers: list[Worker], grace: float | None = None) -> None:
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
        if stop is not None:
            for worker in alive:
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


class WorkerPool:
    """``n_workers`` simulators of ``task_name`` (``mode`` split) with ``env_config``.

    ``step_timeout``: seconds a worker may take per episode start or action before it is killed as hung
    (None: no limit, and with one worker the simulator runs in this process). :attr:`renderer` is the
    renderer the simulators use ("egl" or "tiny"), :attr:`startup_seconds` how long :meth:`start` took.
    """

    def __init__(
        self, task_name: str, mode: str, env_config: EnvConfig, n_workers: int, step_timeout: float | None
    ) -> None:
        self.task_name, self.mode = task_name, mode
        self.env_config = env_config
        self.n_workers = n_workers
        self.step_timeout = step_timeout
        self.workers: list[Worker] = []
        self.startup_seconds = 0.0
        self.renderer: str | None = None
        self._spawned = 0

    def _new_worker(self) -> Worker:
        self._spawned += 1
        in_process = self.n_workers == 1 and self.step_timeout is None
        return Worker(self._spawned - 1, (self.task_name, self.mode, self.env_config), in_process=in_process)

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
                for worker, message in self.receive([w for w in self.workers if not w.ready]):
                    if message[0] == "hung":
                        raise WorkerError(f"worker {worker.index} did not start within {STARTUP_TIMEOUT:.0f} s")
                    if message[0] != "ready":
                        raise WorkerError(f"worker {worker.index} could not start: {message}")
                    self.note_ready(worker)
        except BaseException:
            self.close()
            raise
        self.startup_seconds = time.perf_counter() - begin
        for worker in self.workers:
            self.note_ready(worker)

    def note_ready(self, worker: Worker) -> None:
        """Record the renderer of a worker that said it is ready (warning when it differs from the others')."""
        renderer = worker.info.get("renderer")
        if self.renderer is None:
            self.renderer = renderer
        elif renderer != self.renderer:
            others = self.renderer
            log.warning("evaluation worker %d renders with %s, the others with %s", worker.index, renderer, others)

    def close(self) -> None:
        """Stop every worker (in parallel; within about SHUTDOWN_GRACE + 3 seconds)."""
        workers, self.workers = self.workers, []
        close_all(workers)

    def receive(self, workers: list[Worker]) -> list[tuple[Worker, Message]]:
        """Wait (at most POLL_SECONDS) for messages from ``workers``; a dead worker yields ``("died", exitcode)``
        and one past its deadline is killed and yields ``("hung", seconds waited)``. Possibly empty."""
        local = [(w, w.replies.popleft()) for w in workers if w.stepper is not None and w.replies]
        if local or all(w.stepper is not None for w in workers):
            return local
        remote = [w for w in workers if w.stepper is None]
        by_object: dict[Any, Worker] = {}
        for w in remote:
            by_object[w.conn] = w
            by_object[w.process.sentinel] = w
        deadlines = [w.deadline for w in remote if w.deadline is not None]
        timeout = POLL_SECONDS if not deadlines else min(POLL_SECONDS, max(0.0, min(deadlines) - time.monotonic()))
        out: list[tuple[Worker, Message]] = []
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

    def timeout(self, oracle: bool, worker: Worker) -> float | None:
        """Seconds ``worker`` has for its next answer: the step timeout, times the task's action limit when it
        plays a whole oracle episode."""
        if self.step_timeout is None:
            return None
        return self.step_timeout * (worker.info.get("max_steps", 1) if oracle else 1)

    def replace(self, worker: Worker, kind: str, exitcode: int | None, crashes: dict[int, int], oracle: bool) -> int:
        """Report a dead or hung worker and start another in its place; returns the seed it was playing (to be
        re-run from the start). WorkerError when it was starting, or when the seed has crashed
        :data:`MAX_CRASHES_PER_SEED` times (counted in ``crashes``)."""
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
            reason = f"did not answer within {self.timeout(oracle, worker):.0f} s (hung) and was killed"
        log.warning(
            "evaluation worker %d %s during seed %d of %s-%s; re-running the seed from the start in a new worker",
            worker.index, reason, seed, self.task_name, self.mode,
        )  # fmt: skip
        self.workers[position] = self._new_worker()
        self.workers[position].deadline = time.monotonic() + STARTUP_TIMEOUT
        return seed
