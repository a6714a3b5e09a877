"""The simulator side of the evaluation engine: one environment playing episodes one message at a time.

:class:`EpisodeStepper` runs in each worker process of :class:`~cliport.evaluation.engine.EvalEngine` (or
in the calling process, see there); :func:`worker_main` is a worker process's body. Nothing here imports
torch: workers start fast and never load the agent.
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from cliport.env.environment import EnvConfig, Environment

#: Test hook: "SEED:PATH" makes a worker process die (os._exit) after the first action of SEED (after the
#: whole episode with the oracle) when PATH does not exist yet; it creates PATH first, so the re-run succeeds.
CRASH_ENV = "CLIPORT_TEST_WORKER_CRASH"
#: Test hook: "SEED[,SEED...]:PATH" makes a worker hang (SIGTERM blocked, as in a stuck native call) at the
#: same point of each SEED, when PATH-SEED does not exist yet; it creates PATH-SEED first.
HANG_ENV = "CLIPORT_TEST_WORKER_HANG"


@dataclass
class _Episode:
    seed: int
    scripted: str  # "oracle" or "blind" when a scripted expert plays the whole episode here, else ""
    video_path: str | None
    video_fps: int
    total_reward: float = 0.0
    actions: int = 0
    instruction: str | None = None  # the first instruction of an agent's episode
    start: float = field(default_factory=time.perf_counter)


class EpisodeStepper:
    """One environment with the task; plays episodes one message at a time (see :meth:`handle`).

    Messages: ``("start", seed, scripted, video_path, video_fps)`` (``scripted``: "oracle", "blind" or "" for an
    agent's episode) and ``("action", action)``; replies:
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

    def start(self, seed: int, scripted: str, video_path: str | None = None, video_fps: int = 20) -> tuple[Any, ...]:
        self.episode = _Episode(seed, scripted, video_path, video_fps)
        if video_path is not None:
            self.env.start_recording()
        if scripted:
            from cliport.data.rollout import run_episode, scripted_policy

            played = run_episode(self.env, seed, scripted_policy(self.env, scripted, seed))
            self.episode.total_reward, self.episode.actions = played.total_reward, played.n_actions
            self._maybe_crash()
            return self._finish()
        self.obs = self.env.reset(seed)
        self.lang_goal = self.episode.instruction = self.env.lang_goal
        return self._next()

    def step(self, action: dict[str, Any] | None) -> tuple[Any, ...]:
        episode = self.episode
        if episode is None or episode.scripted:
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
        if episode.instruction is not None:
            row["instruction"] = episode.instruction
        if episode.video_path is not None:
            from cliport.evaluation.visualize import save_video

            save_video(episode.video_path, self.env.stop_recording(), episode.video_fps)
            row["video"] = episode.video_path
        self.episode, self.obs = None, None
        return ("result", row)

    def _maybe_crash(self) -> None:
        if not self.crash_hook or self.episode is None:
            return
        seed, _, path = os.environ.get(CRASH_ENV, "").partition(":")
        if seed and int(seed) == self.episode.seed and not os.path.exists(path):
            open(path, "w").close()
            os._exit(3)
        seeds, _, path = os.environ.get(HANG_ENV, "").partition(":")
        marker = f"{path}-{self.episode.seed}"
        if seeds and self.episode.seed in {int(s) for s in seeds.split(",")} and not os.path.exists(marker):
            open(marker, "w").close()
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
            time.sleep(3600)

    def close(self) -> None:
        self.env.close()


def worker_main(conn: Connection, task_name: str, mode: str, env_config: EnvConfig) -> None:
    """A worker process: build the stepper, say ready, then answer messages until "close" or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    try:
        stepper = EpisodeStepper(task_name, mode, env_config, crash_hook=True)
    except Exception:
        conn.send(("error", traceback.format_exc()))
        return
    assert stepper.env.task is not None
    conn.send(("ready", {"renderer": stepper.env.renderer_kind, "max_steps": stepper.env.task.max_steps}))
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


__all__ = ["CRASH_ENV", "HANG_ENV", "EpisodeStepper", "worker_main"]
