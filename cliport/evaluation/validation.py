"""Validation by task success: every scheduled checkpoint of a run on the val episodes, best one recorded.

``RUN/val.json`` is rewritten atomically after each checkpoint, so an interrupted validation keeps what
it finished and a re-run does only the missing checkpoints; it records the renderer the episodes used.
Each checkpoint's score and success, with their 95% intervals, also go to TensorBoard (``RUN/tensorboard/val/``).
:class:`SimulatorValidator` is what ``cliport-train`` and the study hand to the trainer.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import multiprocessing as mp
import os
import time
from dataclasses import dataclass, fields
from typing import Any

import torch

from cliport.env.environment import EnvConfig
from cliport.evaluation.engine import DEFAULT_STEP_TIMEOUT, EvalEngine, resolve_workers
from cliport.evaluation.evaluate import evaluate, summarise
from cliport.evaluation.workers import POLL_SECONDS
from cliport.utils.files import read_json, write_json
from cliport.utils.run_dir import RunDir
from cliport.utils.tensorboard import log_result, summary_writer

log = logging.getLogger(__name__)


def validate_run(
    run_dir: str,
    task: str,
    n_episodes: int,
    camera_scale: float,
    device: torch.device,
    weights: dict[str, str] | None = None,
    progress: bool = True,
    workers: int | None = None,
    renderer: str | None = None,
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
) -> dict[str, Any]:
    """Evaluate every saved checkpoint of ``run_dir`` not yet in its val.json on ``n_episodes`` val
    episodes of each task of ``task`` (a task or group) in ``workers`` simulators (None: one per usable core, see
    :func:`~cliport.evaluation.engine.resolve_workers`) rendering with ``renderer`` (the workcell setting; None:
    ``configs/env.toml``'s); returns the val.json content. One agent at a time: each is dropped (and, on CUDA, its
    cached memory given back) before the next checkpoint is loaded.
    """
    from cliport import tasks
    from cliport.agents import PickPlaceAgent

    run = RunDir(run_dir)
    results: dict[str, Any] = {"task": task, "n_episodes": n_episodes, "checkpoints": {}}
    if os.path.exists(run.val):
        previous = read_json(run.val)
        if previous.get("n_episodes") == n_episodes:
            results = previous
    todo = [step for step in run.checkpoint_steps() if str(step) not in results["checkpoints"]]
    if not todo:
        return results
    n_workers = resolve_workers(workers, n_episodes, "--val-workers")
    names = tasks.resolve(task)
    with contextlib.ExitStack() as stack:
        tensorboard = summary_writer(run.tensorboard_val)
        stack.callback(tensorboard.close)
        # One task: its workers live across checkpoints. A group starts each task's workers per checkpoint
        # rather than keeping workers x tasks processes alive.
        engines = {}
        if len(names) == 1:
            config = EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer)
            engine = EvalEngine(names[0], "val", config, n_workers, progress, step_timeout=step_timeout)
            engines[names[0]] = stack.enter_context(engine)
        for step in todo:
            agent = PickPlaceAgent.from_pretrained(run.checkpoint(step), device=device, weights=weights)
            evaluated = [
                evaluate(agent, name, "val", n_episodes, camera_scale, progress, workers=n_workers,
                         engine=engines.get(name), renderer=renderer, step_timeout=step_timeout)
                for name in names
            ]  # fmt: skip
            del agent
            if device.type == "cuda":
                torch.cuda.empty_cache()  # beside training, the memory is training's again
            scores = [e["mean_score"] for e in evaluated]
            _record_renderer(results, evaluated[0]["renderer"], run.val)
            # Every task has n_episodes, so the pooled episodes' mean is the mean over tasks; their intervals too.
            pooled = summarise(task, "val", [row for e in evaluated for row in e["episodes"]])
            results["checkpoints"][str(step)] = {
                "mean_score": round(sum(scores) / len(scores), 2),
                "per_task": scores,
                **{k: pooled[k] for k in ("ci95", "success_rate", "success_ci95")},
            }
            log_result(tensorboard, "val", pooled, step)
            if len(evaluated) > 1:
                for name, e in zip(names, evaluated, strict=True):
                    log_result(tensorboard, f"val/{name}", e, step)
            tensorboard.flush()
            best = max(results["checkpoints"].items(), key=lambda kv: (kv[1]["mean_score"], -int(kv[0])))
            results["best_step"], results["best_score"] = int(best[0]), best[1]["mean_score"]
            write_json(run.val, results)
            score = sum(scores) / len(scores)
            log.info("validation: step %d scored %.2f on %d val episode(s)", step, score, n_episodes)
    return results


def _record_renderer(results: dict[str, Any], renderer: str, path: str) -> None:
    previous = results.get("renderer")
    if previous is not None and previous != renderer:
        log.warning(
            "%s: earlier checkpoints were validated with the %s renderer, these with %s; their scores are not "
            "comparable (their pixels differ)", path, previous, renderer,
        )  # fmt: skip
        results["renderer"] = "mixed"
    elif previous is None:
        results["renderer"] = renderer


@dataclass
class SimulatorValidator:
    """Validates a run's checkpoints in the simulator once training has finished (see ``Validator``);
    its fields are :func:`validate_run`'s arguments."""

    run_dir: str
    task: str
    n_episodes: int
    camera_scale: float
    device: torch.device
    weights: dict[str, str] | None = None
    progress: bool = True
    workers: int | None = None
    renderer: str = "auto"
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT

    def checkpoint_saved(self, step: int, path: str) -> None:
        """Nothing to do yet: checkpoints are validated together in :meth:`finish`."""

    def finish(self) -> dict[str, Any]:
        return validate_run(**{f.name: getattr(self, f.name) for f in fields(self)})


def _validate_as_checkpoints_arrive(arguments: dict[str, Any], steps: Any) -> None:
    """Body of the background validation process: after each announced step, validate every saved
    checkpoint not yet in val.json (this process is val.json's only writer); None ends it."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    while steps.get() is not None:
        validate_run(**arguments)


@dataclass
class BackgroundValidator(SimulatorValidator):
    """Validates each checkpoint in a separate process while training goes on, so the trainer never waits
    for the simulator; ``finish()`` waits for the last validation. val.json is updated atomically as
    results arrive, and a resumed run validates whatever a killed one had not (validate_run skips the rest).
    The process holds its own copy of the agent on the same device."""

    def __post_init__(self) -> None:
        self._process: Any = None
        self._steps: Any = None

    def checkpoint_saved(self, step: int, path: str) -> None:
        if self._process is None:
            context = mp.get_context("spawn")
            self._steps = context.Queue()
            arguments = {f.name: getattr(self, f.name) for f in fields(SimulatorValidator)}
            arguments["progress"] = False  # the training bar owns the terminal
            self._process = context.Process(
                target=_validate_as_checkpoints_arrive, args=(arguments, self._steps), name="cliport-validation"
            )
            self._process.start()
            atexit.register(self._stop, 30.0)  # an interrupted training must not wait for validation forever
        self._steps.put(step)

    def _stop(self, timeout: float | None) -> int | None:
        if self._process is None:
            return None
        if self._process.is_alive():
            self._steps.put(None)
            end = None if timeout is None else time.monotonic() + timeout
            # Bounded joins: a Ctrl-C that lands just before a blocking join would wait for all of it.
            while self._process.is_alive() and (end is None or time.monotonic() < end):
                self._process.join(POLL_SECONDS if end is None else min(POLL_SECONDS, end - time.monotonic()))
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(5)
                if self._process.is_alive():
                    self._process.kill()
                    self._process.join()
        code = self._process.exitcode
        self._process = None
        atexit.unregister(self._stop)
        return code

    def finish(self) -> dict[str, Any]:
        code = self._stop(None)
        if code not in (None, 0):
            log.warning("the validation process ended with exit code %s; validating what it left here", code)
        return super().finish()  # validates anything still missing, then returns val.json's content


def make_validator(mode: str, device: torch.device, **arguments: Any) -> SimulatorValidator:
    """A validator for ``mode`` "after" (all checkpoints once training ends), "beside" (each one in a
    background process as it is saved) or "auto" (beside on CUDA; after on a CPU, where the simulator
    would compete with training for the cores)."""
    if mode == "auto":
        mode = "beside" if device.type == "cuda" else "after"
    cls = {"after": SimulatorValidator, "beside": BackgroundValidator}[mode]
    return cls(device=device, **arguments)
