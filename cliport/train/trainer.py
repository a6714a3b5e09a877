"""Training: a step loop over augmented demonstration batches with scheduled checkpoints, a rolling resume point,
metrics, optional DDP (torchrun) and mixed precision. On CUDA the step is replayed as one CUDA graph at the run's
batch shape (:mod:`cliport.train.graphed_step`); the losses stay on the device and are read every ``log_every``
steps.

:func:`train` runs the named steps of a run, each in a module of its own: the set-up (:mod:`cliport.train.run`,
whose :class:`~cliport.train.run.TrainRun` holds the state the steps share), the resume or the first draw of
nets that can learn (:mod:`cliport.train.resume`), the step loop with its checks (:mod:`cliport.train.step_loop`,
:mod:`cliport.train.checks`), and what is saved and logged (:mod:`cliport.train.saving`). The run folder's layout
is :mod:`cliport.utils.run_dir`; reading a run's saved config is :func:`cliport.train.config.load_run_config`.

Validation is not this module's business: the caller passes a :class:`~cliport.train.saving.Validator`
(``cliport.evaluation.validation`` has the simulator one), which hears of every saved checkpoint and is finished
when training ends, or an :class:`~cliport.train.checks.AgentCheck` that scores the training agent itself at the
steps it asks for (the language lesson's held-out scenes), whose best step's checkpoint is kept.

A run with a ``time_budget_s`` trains until that many seconds of its training loop (checks and saves included,
summed over resumes) have passed, or ``n_steps``; the step it stops at is checkpointed like ``n_steps``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch.distributed as dist

from cliport.errors import TrainError
from cliport.train.checks import AgentCheck
from cliport.train.config import TrainConfig
from cliport.train.resume import resume_from_last, start_live
from cliport.train.run import TrainRun, set_up
from cliport.train.saving import Validator, checkpoint_schedule, write_run_config
from cliport.train.step_loop import StepLoop, autocast_dtype

__all__ = ["TrainError", "Validator", "autocast_dtype", "checkpoint_schedule", "train"]


def train(
    config: TrainConfig,
    resume: bool = False,
    progress: bool = True,
    validator: Validator | None = None,
    step_hook: Callable[[int], None] | None = None,
    check: AgentCheck | None = None,
) -> dict[str, Any]:
    """Train (or resume) a run; returns a summary. ``validator`` (on rank 0) scores the checkpoints.
    ``step_hook(step)`` is called after every optimiser step (a benchmark's profiler; the lesson's speed line).
    ``check`` (single process only) scores the agent at the steps it asks for and at the last step; the best
    step's scheduled checkpoint is kept (``RUN/held_out.json``, :mod:`cliport.train.checks`)."""
    run = set_up(config, resume, check)
    if resume:
        resume_from_last(run)
    start_live(run)
    write_run_config(run)
    loop = StepLoop(run, validator, check, progress, step_hook)
    try:
        loop.run()
    except KeyboardInterrupt:
        loop.saver.save("last")
        raise
    finally:
        loop.log.close()
    return _summary(run, loop, validator)


def _summary(run: TrainRun, loop: StepLoop, validator: Validator | None) -> dict[str, Any]:
    """What :func:`train` returns: the run folder, steps and checkpoints, seconds trained, nets drawn again, why it
    stopped, the best check, how its steps ran (graph replays, eager steps), validation, and this process's rank."""
    folder = run.folder
    summary: dict[str, Any] = {"run_dir": folder.root, "steps": run.step, "checkpoints": folder.checkpoint_steps()}
    summary["trained_s"] = round(run.trained_s(), 1)
    summary["init_draws"] = run.init_draws
    summary["stopped_by"] = "time_budget" if run.step < run.config.n_steps else "n_steps"
    if loop.curve is not None and loop.curve.best is not None:
        summary["held_out"] = {"best_step": loop.curve.best["step"], "best_score": loop.curve.best["score"]}
    # How this process's steps ran: replays of the captured CUDA graph, eager steps (warm-up included).
    step = loop.train_step
    summary["step_kinds"] = {"graph_replays": step.replays, "eager": step.eager_steps}
    if step.failed:
        summary["step_kinds"]["capture_failed"] = step.failed
    if run.rank == 0 and validator is not None:
        summary["validation"] = validator.finish()
    if run.world > 1:
        dist.barrier()
    summary["rank"] = run.rank
    return summary
