"""A training run's step loop (:class:`StepLoop`): the optimiser step (:class:`~cliport.train.graphed_step.TrainStep`:
one CUDA graph on CUDA, eager elsewhere and under DDP) over the loader's batches, and after each step what the
schedule asks for: a row of metrics, a check of the agent (:mod:`cliport.train.checks`), a scheduled checkpoint,
the rolling resume point (:mod:`cliport.train.saving`). Dead maps stop the run before it saves them
(:mod:`cliport.train.dead_maps`); the losses stay on the device between rows (:mod:`cliport.train.loss_sums`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader

from cliport.agents.base import PickPlaceAgent
from cliport.errors import UserError
from cliport.train import graphed_step
from cliport.train.checks import AgentCheck, CheckCurve, check_line
from cliport.train.config import TrainConfig
from cliport.train.dead_maps import DeadMapWatch
from cliport.train.graphed_step import TrainStep
from cliport.train.loader import training_loader
from cliport.train.loss_sums import LossSums
from cliport.train.run import TrainRun
from cliport.train.saving import RunLog, Saver, Validator, checkpoint_schedule
from cliport.utils.device import bf16_native


class StepLoop:
    """The step loop of ``run`` from its current step: builds the step, the loader and the writers, then
    :meth:`run` trains. ``check`` (rank 0) scores the agent at the steps it asks for; ``step_hook(step)`` is called
    after every optimiser step."""

    def __init__(
        self,
        run: TrainRun,
        validator: Validator | None,
        check: AgentCheck | None,
        progress: bool,
        step_hook: Callable[[int], None] | None,
    ) -> None:
        config, device = run.config, run.device
        self.train_run, self.check, self.step_hook = run, check, step_hook
        self.sums = LossSums(device)
        self.watch = DeadMapWatch(device=device, start_step=run.step)
        self.train_step = _train_step(run, (self.sums.add, self.watch.observe))
        loader: DataLoader = training_loader(
            run.dataset,
            config.batch_size,
            run.agent.config.n_rotations,
            config.num_workers,
            seed=config.seed * 7919 + run.rank + run.step,
            pin_memory=device.type == "cuda",
            pair_contrasts=config.pair_contrasts,
        )
        self.schedule = set(checkpoint_schedule(config))
        self.curve = None
        if check is not None and run.rank == 0:
            self.curve = CheckCurve(run.folder.held_out, check.describe(), run.step)
        run.start_clock()
        self.saver = Saver(run, validator)
        self.log = RunLog(run, progress)
        self.batches = _batches(loader)
        self.ended_final = False

    def run(self) -> None:
        """Train until ``n_steps`` or the time budget, then make sure the last step was saved and checked."""
        run = self.train_run
        self.log.open_metrics()
        run.agent.train()
        while run.step < run.config.n_steps and not run.out_of_time():
            run.cooldown.apply(run.fraction())
            self.train_step(_next_batch(self.batches))
            run.step += 1
            self.sums.count()
            self.log.count()
            if self.step_hook is not None:
                self.step_hook(run.step)
            self.end_of_step(run.finished())
        if run.step and not self.ended_final and run.finished():
            # The budget ran out during the last step's check or saves, or an earlier attempt stopped before its
            # last step was saved: finish it as the last step.
            saved = os.path.exists(run.folder.checkpoint(run.step))
            if not saved or (self.curve is not None and not self.curve.has(run.step)):
                self.end_of_step(True)

    def end_of_step(self, final: bool) -> None:
        """Log, check and save after the run's step as the schedule asks (``final``: the run's last step)."""
        run = self.train_run
        step, self.ended_final = run.step, final
        if self.log.due(step, final):
            losses = self.sums.read()  # waits for the device
            self.watch.check()
            self.log.write(losses, step)
        checking = self.curve is not None and (self._check_due(step) or final) and not self.curve.has(step)
        scheduled = step in self.schedule or final
        keep_last = scheduled or checking or step % run.config.save_last_every == 0
        if keep_last:
            self.watch.check()  # never save a run whose map died since the last row
        if scheduled:
            self.saver.save(step)
        replaced = self._check_agent(step, scheduled) if checking else None
        if keep_last:
            self.saver.save("last")
        if replaced is not None:
            self.saver.remove(replaced)  # after last.pt: a resume from before it still finds it

    def _check_due(self, step: int) -> bool:
        return self.check is not None and self.check.due(step)

    def _check_agent(self, step: int, scheduled: bool) -> int | None:
        """Check the agent after ``step``; a new best step's checkpoint is kept (saved here if the schedule did not
        save it). Returns the step of the checkpoint it replaces, if the schedule would not have kept that one."""
        assert self.curve is not None and self.check is not None
        previous = self.curve.best
        checked, best = self.curve.run(self.check, step, self.train_run.agent)
        self.train_run.agent.train()
        self.log.bar.write(check_line(checked, best))
        if best:
            self.log.scalar("held_out/score", checked["score"], step)
            if not scheduled:
                self.saver.save(step)
            if previous is not None and previous["step"] not in self.schedule:
                return int(previous["step"])
        return None


def autocast_dtype(config: TrainConfig, device: torch.device) -> torch.dtype | None:
    """The dtype a training step of ``config`` autocasts to on ``device`` (``amp``: bf16 where asked, or where
    ``auto`` finds native bf16), or None for full precision."""
    use_amp = config.amp == "bf16" or (config.amp == "auto" and bf16_native(device))
    return torch.bfloat16 if use_amp else None


class _LossModule(nn.Module):
    """Wraps an agent so that DDP sees ``forward(batch) -> (loss, terms)`` with the recipe's loss (the (3,)
    terms of :meth:`~cliport.agents.base.PickPlaceAgent._loss_terms`, on the device)."""

    def __init__(self, agent: PickPlaceAgent, loss: str) -> None:
        super().__init__()
        self.agent = agent
        self.loss = loss

    def forward(self, batch: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.agent._loss_terms(**self.agent.training_inputs(batch), loss=self.loss)


def _train_step(run: TrainRun, observers: tuple[Callable[[torch.Tensor], None], ...]) -> TrainStep:
    """The run's optimiser step: captured as a CUDA graph where it can be, eager under DDP (its gradient
    all-reduce would need its own warm-up and stream set-up to be captured) and with a learning-rate cooldown."""
    config, device, single = run.config, run.device, run.world == 1
    model = None
    if not single:
        ddp_ids = [run.local_rank] if device.type == "cuda" else None
        model = nn.parallel.DistributedDataParallel(_LossModule(run.agent, run.recipe.loss), device_ids=ddp_ids)
    graphs = config.train_graphs and single
    if graphs and config.lr_cooldown > 0 and device.type in graphed_step.CAPTURE_DEVICES:
        graphs = False
        run.note("the learning-rate cooldown trains eagerly (a captured step holds its learning rate fixed)")
    return TrainStep(
        run.agent,
        run.optimizer,
        run.recipe.loss,
        autocast_dtype=autocast_dtype(config, device),
        observers=observers,
        graphs=graphs,
        compile=config.compile and single,
        model=model,
        parallel_heads=config.parallel_heads and single,
    )


def _batches(loader: DataLoader) -> Iterator[dict[str, Any]]:
    while True:
        yield from loader


def _next_batch(batches: Iterator[dict[str, Any]]) -> dict[str, Any]:
    """The next batch; a user error raised in a DataLoader worker comes back as itself, one line."""
    try:
        return next(batches)
    except Exception as e:
        # DataLoader re-raises worker exceptions as the same class with the worker's traceback in the message.
        message = str(e)
        if isinstance(e, UserError) and "Traceback" in message:
            lines = [line for line in message.strip().splitlines() if line.strip()]
            raise type(e)(lines[-1].split(": ", 1)[-1]) from None
        raise
