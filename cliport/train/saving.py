"""What a training run saves and logs (the layout is :mod:`cliport.utils.run_dir`): its resolved config, the
checkpoints of the schedule (each also as safetensors, the newest as ``RUN/model.safetensors``, and announced to
the :class:`Validator`), the rolling resume point ``last.pt``, the rows of ``metrics.csv``, TensorBoard scalars and
the progress bar. Only the first process (rank 0) writes; the others count their steps.
"""

from __future__ import annotations

import contextlib
import csv
import os
import time
from typing import IO, Any, Protocol

import torch
from tqdm import tqdm

from cliport.agents.checkpoint import save_weights
from cliport.train.config import TrainConfig
from cliport.train.run import TrainRun
from cliport.utils.files import link_or_copy, save_torch, write_json
from cliport.utils.tensorboard import log_gpu_memory, summary_writer

#: The columns of ``metrics.csv``.
METRICS_FIELDS = ["step", "loss", "pick_loss", "place_loss", "steps_per_second", "samples_per_second", "elapsed_s"]


class Validator(Protocol):
    """Scores checkpoints of a run; called by :func:`~cliport.train.trainer.train` on the process that saves them."""

    def checkpoint_saved(self, step: int, path: str) -> None:
        """A scheduled checkpoint has been written (validation may start now or be queued)."""

    def finish(self) -> dict[str, Any]:
        """Training has ended: validate whatever is left and return the results."""


def checkpoint_schedule(config: TrainConfig) -> list[int]:
    """Steps with a saved checkpoint: the listed ones up to n_steps, then every checkpoint_every, and n_steps."""
    steps = {s for s in config.checkpoint_steps if s <= config.n_steps}
    last = max(steps, default=0)
    if config.checkpoint_every > 0:
        s = (last // config.checkpoint_every + 1) * config.checkpoint_every
        while s <= config.n_steps:
            steps.add(s)
            s += config.checkpoint_every
    steps.add(config.n_steps)
    return sorted(steps)


def write_run_config(run: TrainRun) -> None:
    """``RUN/config.json``: the run's resolved config (the run folder is made here)."""
    if run.rank == 0:
        os.makedirs(run.folder.root, exist_ok=True)
        write_json(run.folder.config, run.config.to_dict())


class Saver:
    """The checkpoints of one run: scheduled steps and the rolling ``last.pt`` (written on rank 0 only)."""

    def __init__(self, run: TrainRun, validator: Validator | None) -> None:
        self.run = run
        self.validator = validator

    def save(self, kind: int | str) -> None:
        """Save the agent as scheduled step ``kind`` (``.pt``, ``.safetensors``, ``RUN/model.safetensors``; the
        validator hears of it) or, for ``"last"``, as the resume point with the trainer's state."""
        run = self.run
        if run.rank != 0:
            return
        payload = {**run.agent.checkpoint_payload(), "recipe": run.config.recipe, "init_draws": run.init_draws}
        if kind == "last":
            payload["trainer"] = {
                "step": run.step,
                "optimizer": run.optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
                "trained_s": round(run.trained_s(), 3),
            }
        save_torch(payload, run.folder.checkpoint(kind))
        if isinstance(kind, int):  # a scheduled step, not "last"
            save_weights(payload, run.folder.weights(kind), step=kind)  # safetensors beside the .pt
            link_or_copy(run.folder.weights(kind), run.folder.model_weights)  # RUN/model.safetensors: the newest one
            if self.validator is not None:
                self.validator.checkpoint_saved(kind, run.folder.checkpoint(kind))

    def remove(self, step: int) -> None:
        """Delete a scheduled checkpoint a better one replaced (its .pt and .safetensors)."""
        for path in (self.run.folder.checkpoint(step), self.run.folder.weights(step)):
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)


class RunLog:
    """The rows of ``metrics.csv`` (one per ``log_every`` steps and at the last step: mean losses and throughput of
    the steps since the last row), their TensorBoard scalars and the progress bar."""

    def __init__(self, run: TrainRun, progress: bool) -> None:
        self.run = run
        first = run.rank == 0
        purge = run.step + 1 if run.step else None
        self.tensorboard = summary_writer(run.folder.tensorboard, purge_step=purge) if first else None
        desc = f"train {run.config.agent}"
        self.bar = tqdm(total=run.config.n_steps, initial=run.step, desc=desc, disable=not progress or not first)
        self.start = self.window_start = time.perf_counter()
        self.window_steps = 0
        self._file: IO[str] | None = None
        self._writer: csv.DictWriter[str] | None = None

    def open_metrics(self) -> None:
        """Open ``metrics.csv`` for appending (rank 0), with its header if it is new."""
        if self.run.rank != 0:
            return
        self._file = open(self.run.folder.metrics, "a", newline="")  # closed by close()
        self._writer = csv.DictWriter(self._file, fieldnames=METRICS_FIELDS)
        if self._file.tell() == 0:
            self._writer.writeheader()

    def count(self) -> None:
        """One more step trained."""
        self.window_steps += 1
        self.bar.update(1)

    def due(self, step: int, final: bool) -> bool:
        """Whether a row is due after ``step`` (``final``: the run's last step)."""
        return bool(self.window_steps) and (step % self.run.config.log_every == 0 or final)

    def write(self, losses: dict[str, float], step: int) -> None:
        """The row of ``step``: ``losses`` (means since the last row), steps and samples per second, and the
        seconds since the loop began; also as TensorBoard scalars (with the learning rate and GPU memory)."""
        config = self.run.config
        row: dict[str, Any] = {k: round(v, 5) for k, v in losses.items()}
        elapsed = time.perf_counter() - self.window_start
        row.update(
            step=step,
            steps_per_second=round(self.window_steps / elapsed, 3),
            samples_per_second=round(self.window_steps * config.batch_size * self.run.world / elapsed, 2),
            elapsed_s=round(time.perf_counter() - self.start, 1),
        )
        if self._writer is not None and self._file is not None:
            self._writer.writerow(row)
            self._file.flush()
        if self.tensorboard is not None:
            for key in ("loss", "pick_loss", "place_loss", "samples_per_second"):
                self.tensorboard.add_scalar(f"train/{key}", row[key], step)
            self.tensorboard.add_scalar("train/learning_rate", self.run.optimizer.param_groups[0]["lr"], step)
            log_gpu_memory(self.tensorboard, self.run.device, step)
        self.bar.set_postfix(loss=f"{row['loss']:.3f}", steps_s=f"{row['steps_per_second']:.2f}")
        self.window_start, self.window_steps = time.perf_counter(), 0

    def scalar(self, tag: str, value: float, step: int) -> None:
        """One more TensorBoard scalar (rank 0)."""
        if self.tensorboard is not None:
            self.tensorboard.add_scalar(tag, value, step)

    def close(self) -> None:
        """Close the bar, the metrics file and the TensorBoard writer."""
        self.bar.close()
        if self._file is not None:
            self._file.close()
        if self.tensorboard is not None:
            self.tensorboard.close()
