"""One cell of the study, run exactly once: train (or resume), validate and test every checkpoint, record it.

A cell keeps its records in ``TASK_DIR/cells/NAME/`` (NAME = its run folder's name):

::

    result.json      the completion record: the run's summary (a row of the table), minutes, host; written by
                     atomic rename as the cell's last act, so it exists only for a finished cell
    attempts.jsonl   one line per attempt's start (pid, host, the step it resumed from) and one per completion,
                     appended: what happened after a crash
    .lock            locked (flock) while an attempt runs: one attempt at a time, and ``--status`` sees it
    log.txt          the cell's output when it ran as a Ray task

A cell that finds its ``result.json`` returns it and does nothing else; an attempt that finds another still
running (a worker Ray gave up on that has not died yet) waits for it to end, then looks again. Everything else
it writes (checkpoints, val.json, test results) is written atomically by the trainer and the evaluation, and a
killed attempt's successor resumes from ``checkpoints/last.pt`` and evaluates only what is missing. Everything
a cell computes depends on its own settings and seeds: its torch thread count is set explicitly
(:attr:`StudyConfig.threads`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
from typing import Any

from cliport.errors import UserError
from cliport.study.config import Cell, StudyConfig
from cliport.study.lock import FileLock
from cliport.study.report import summarise_run
from cliport.utils.files import read_json, write_json
from cliport.utils.run_dir import RunDir


class CellError(UserError, RuntimeError):
    """Cells of the study failed; the message names the first, its error's first line and where its log is."""


class CellFiles:
    """The paths of one cell's records (see the module docstring)."""

    def __init__(self, config: StudyConfig, cell: Cell) -> None:
        self.run_dir = config.run_dir(cell)
        self.name = os.path.basename(self.run_dir)
        self.folder = os.path.join(config.task_dir(cell.task), "cells", self.name)
        self.result = os.path.join(self.folder, "result.json")
        self.lock = os.path.join(self.folder, ".lock")
        self.attempts = os.path.join(self.folder, "attempts.jsonl")
        self.log = os.path.join(self.folder, "log.txt")

    def record(self) -> dict[str, Any] | None:
        """The completion record, or None while the cell is not finished."""
        return read_json(self.result) if os.path.exists(self.result) else None

    def attempt_log(self) -> list[dict[str, Any]]:
        """The attempts' events, oldest first (a line cut short by a crash is skipped)."""
        if not os.path.exists(self.attempts):
            return []
        events = []
        with open(self.attempts) as f:
            for line in f:
                try:
                    events.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
        return events

    def log_event(self, event: dict[str, Any]) -> None:
        os.makedirs(self.folder, exist_ok=True)
        with open(self.attempts, "a") as f:
            f.write(json.dumps(event) + "\n")
            f.flush()
            os.fsync(f.fileno())


def resume_step(run: RunDir) -> int:
    """The step a (re)started training run continues from: that of ``checkpoints/last.pt``, 0 without one."""
    path = run.checkpoint("last")
    if not os.path.exists(path):
        return 0
    import torch

    try:  # memory-mapped: only the step is read, not the optimiser state
        return int(torch.load(path, map_location="cpu", weights_only=True, mmap=True)["trainer"]["step"])
    except Exception:
        return 0  # unreadable: the trainer reports it when it resumes


def run_cell(config: StudyConfig, cell: Cell, progress: bool = True) -> dict[str, Any]:
    """Run (or resume, or merely read) one cell; returns its completion record (``summary``: its row)."""
    files = CellFiles(config, cell)
    done = files.record()
    if done is not None:
        return done
    waiting = f"{cell.label()}: waiting for an earlier attempt that still runs"
    with FileLock(files.lock, wait=True, waiting=waiting):
        return files.record() or _attempt(config, cell, files, progress)


def _attempt(config: StudyConfig, cell: Cell, files: CellFiles, progress: bool) -> dict[str, Any]:
    import torch

    torch.set_num_threads(config.threads)
    train_config = config.train_config(cell.agent, cell.n_demos, cell.seed, cell.recipe, cell.task)
    run = RunDir(train_config.resolved_run_dir())
    attempt = 1 + sum(e["event"] == "start" for e in files.attempt_log())
    start = {
        "event": "start",
        "attempt": attempt,
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "time": time.time(),
        "resume_step": resume_step(run),
    }
    files.log_event(start)
    began = time.perf_counter()
    summary = _train_and_evaluate(config, cell, train_config, run, progress)
    minutes = round((time.perf_counter() - began) / 60, 2)
    record = {
        "cell": dataclasses.asdict(cell),
        "summary": summary,
        "minutes": minutes,
        "attempt": attempt,
        "resumed_from_step": start["resume_step"],
        "host": start["host"],
        "finished": time.time(),
        "environment": _environment(),
    }
    write_json(files.result, record)  # the completion: an atomic rename
    files.log_event({"event": "done", "attempt": attempt, "pid": os.getpid(), "time": time.time(), "minutes": minutes})
    return record


def _train_and_evaluate(config: StudyConfig, cell: Cell, train_config: Any, run: RunDir, progress: bool) -> dict:
    """Train (or resume) the cell's run, validate and test every checkpoint; its summary (a row, with seed)."""
    from cliport.agents import PickPlaceAgent
    from cliport.evaluation.evaluate import evaluate
    from cliport.evaluation.validation import make_validator, validate_run
    from cliport.train.trainer import train
    from cliport.utils.device import resolve_device

    device = resolve_device(train_config.device)
    validate = config.val_episodes > 0
    val_workers = config.eval_worker_count(config.val_episodes) if validate else None
    test_workers = config.eval_worker_count(config.test_episodes)
    if run.checkpoint_steps()[-1:] != [config.n_steps]:
        validator = None
        if validate:
            validator = make_validator(
                train_config.val_mode,
                device,
                run_dir=run.root,
                task=cell.task,
                n_episodes=config.val_episodes,
                camera_scale=config.camera_scale,
                progress=progress,
                workers=val_workers,
                renderer=train_config.env.renderer,
            )
        train(train_config, resume=run.is_run(), progress=progress, validator=validator)
    elif validate:
        validate_run(
            run.root,
            cell.task,
            config.val_episodes,
            config.camera_scale,
            device,
            None,
            progress,
            val_workers,
            renderer=train_config.env.renderer,
        )
    test: dict[str, float] = {}
    for step in run.checkpoint_steps():
        path = os.path.join(run.eval_dir, f"{cell.task}-test-{step}.json")
        if not os.path.exists(path):
            agent = PickPlaceAgent.from_pretrained(run.checkpoint(step), device=device)
            result = evaluate(
                agent,
                cell.task,
                "test",
                config.test_episodes,
                config.camera_scale,
                progress,
                workers=test_workers,
                renderer=train_config.env.renderer,
            )
            result.update(
                checkpoint=step, agent=cell.agent, recipe=cell.recipe, weight_sources=agent.weight_source_values()
            )
            write_json(path, result)
        test[str(step)] = read_json(path)["mean_score"]
    val = read_json(run.val) if os.path.exists(run.val) else {"checkpoints": {}}
    return {**summarise_run(cell.task, cell.agent, cell.n_demos, test, val, cell.recipe), "seed": cell.seed}


def generate_demos(config: StudyConfig, task: str, shard: int, progress: bool = True) -> dict[str, Any]:
    """Shard ``shard`` of ``config.demo_shards`` of the task's training demos (the most any cell uses)."""
    from cliport.data.generate import DemoConfig, generate

    demo_config = DemoConfig.defaults(
        data_dir=config.data_dir, workers=config.demo_workers, camera_scale=config.camera_scale
    )
    shards = (shard, config.demo_shards)
    return generate(task, "train", max(config.n_demos), demo_config, shard=shards, progress=progress)


def _environment() -> dict[str, Any]:
    """The machine's record (imported here: the study's --help must not import torch)."""
    from cliport.utils.machine import measurement_environment

    return measurement_environment()
