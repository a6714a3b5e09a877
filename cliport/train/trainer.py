"""Training: a step loop over augmented demonstration batches with scheduled checkpoints, a rolling
resume point, metrics, optional DDP (torchrun) and mixed precision. On CUDA the step is replayed as one CUDA
graph at the run's batch shape (:mod:`cliport.train.graphed_step`); the losses stay on the device and are
read every ``log_every`` steps.

The run folder's layout is :mod:`cliport.utils.run_dir`. Validation is not this module's business: the
caller passes a :class:`Validator` (``cliport.evaluation.validation`` has the simulator one), which
hears of every saved checkpoint and is finished when training ends, or an
:class:`~cliport.train.checks.AgentCheck` that scores the training agent itself at the steps it asks for (the
language lesson's held-out scenes), whose best step's checkpoint is kept.

A run with a ``time_budget_s`` trains until that many seconds of its training loop (checks and saves included,
summed over resumes) have passed, or ``n_steps``; the step it stops at is checkpointed like ``n_steps``.
"""

from __future__ import annotations

import contextlib
import csv
import os
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader
from tqdm import tqdm

from cliport.agents.base import PickPlaceAgent
from cliport.agents.checkpoint import save_weights
from cliport.env.config import expected_renderer
from cliport.errors import RunDirError, UserError
from cliport.train import graphed_step
from cliport.train.checks import AgentCheck, CheckCurve
from cliport.train.config import TrainConfig
from cliport.train.dead_maps import DeadMapWatch
from cliport.train.graphed_step import TrainStep
from cliport.train.live_start import ensure_live
from cliport.train.loader import TrainingCollate, training_loader
from cliport.train.loss_sums import LossSums
from cliport.train.lr_schedule import LrCooldown
from cliport.train.resume import load_optimizer_state
from cliport.utils.device import bf16_native, resolve_device
from cliport.utils.files import link_or_copy, load_torch, save_torch, write_json
from cliport.utils.run_dir import RunDir
from cliport.utils.tensorboard import log_gpu_memory, summary_writer


class TrainError(RunDirError):
    """A training run cannot start or resume as asked; the message says why."""


class Validator(Protocol):
    """Scores checkpoints of a run; called by :func:`train` on the process that saves them."""

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


def load_run_config(run_dir: str) -> TrainConfig:
    """The resolved config a run saved (any layout version); RunDirError if the folder is not a run."""
    run = RunDir(run_dir)
    if not os.path.isdir(run_dir):
        raise RunDirError(f"run folder not found: {run_dir}")
    if not run.is_run():
        raise RunDirError(f"{run_dir} is not a training run (no config.json)")
    from cliport.utils.files import read_json

    return TrainConfig.from_saved(read_json(run.config))


class _LossModule(nn.Module):
    """Wraps an agent so that DDP sees ``forward(batch) -> (loss, terms)`` with the recipe's loss (the (3,)
    terms of :meth:`~cliport.agents.base.PickPlaceAgent.loss_terms`, on the device)."""

    def __init__(self, agent: PickPlaceAgent, loss: str) -> None:
        super().__init__()
        self.agent = agent
        self.loss = loss

    def forward(self, batch: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.agent.loss_terms(**self.agent.training_inputs(batch), loss=self.loss)


def _distributed() -> tuple[int, int, int]:
    """(rank, world size, local rank); initialises the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, 0
    if not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        torch.cuda.set_device(local)
    return dist.get_rank(), world, local


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


def _check_start(config: TrainConfig, resume: bool) -> RunDir:
    run = RunDir(config.resolved_run_dir())
    if resume:
        if not run.is_run():
            raise TrainError(f"nothing to resume in {run.root}: it holds no run (no config.json)")
        return run
    if run.is_run():
        if run.has_progress():
            raise TrainError(
                f"run folder {run.root} already holds a run: pass --resume to continue it, or choose --run-dir"
            )
        # A run that died before its first save has nothing to lose: start it again from scratch.
    return run


def _check_demo_rendering(dataset: Any, config: TrainConfig) -> None:
    """Validation must render as the demos were rendered: same camera scale, same renderer."""
    if config.val_episodes == 0:
        return
    for task, scale in dataset.recorded_camera_scales().items():
        if scale is not None and abs(scale - config.env.camera_scale) > 1e-9:
            raise TrainError(
                f"the {task} demos were rendered at camera_scale {scale} but validation would render at "
                f"{config.env.camera_scale}: pass --camera-scale {scale}"
            )
    validation = expected_renderer(config.env.renderer)
    for task, renderer in dataset.recorded_renderers().items():
        if renderer is not None and renderer != validation:
            flag = "cpu" if renderer == "tiny" else "egl"
            raise TrainError(
                f"the {task} demos were rendered with {renderer} but validation would render with {validation} "
                f"(renderer {config.env.renderer!r} on this machine): pass --renderer {flag}"
            )


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
    from cliport.agents import make_agent, read_checkpoint
    from cliport.data.dataset import DemoDataset

    rank, world, local_rank = _distributed()
    run = _check_start(config, resume)
    last_path = run.checkpoint("last")
    if world > 1:
        dist.barrier()  # every rank has checked the run folder before rank 0 writes into it
    device = resolve_device(config.device)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", local_rank)
    torch.manual_seed(config.seed * 1000 + rank)

    recipe = config.training_recipe()
    agent = make_agent(config.agent, config.agent_config).to(device)
    optimizer, applied = recipe.prepare(agent)
    cooldown = LrCooldown(optimizer, config.lr_cooldown)  # before a resume loads the cooled rates
    if recipe.encoder_norms == "train" and not applied and agent.encoder is not None and agent.encoder.norm_stats():
        if rank == 0:
            print(
                f"note: the {recipe.name} recipe trains the frozen encoder's batch norms per net, but "
                f"{agent.name} keeps no per-net statistics: its encoder stays in inference mode",
                file=sys.stderr,
            )
    dataset = DemoDataset(
        config.data_dir,
        config.task,
        "train",
        config.n_demos,
        seed=config.seed,
        rotation_aug=config.rotation_aug,
        aug_pivot=recipe.aug_pivot,
        aug_interpolation=recipe.aug_interpolation,
        every_instruction=config.every_instruction,
    )
    _check_demo_rendering(dataset, config)
    if agent.centers_sentences:
        fitted = agent.fit_sentence_centering(dataset.instructions())
        if rank == 0:
            print(
                f"sentence features centred on the training set's {fitted['instructions']} instructions "
                f"(scale {fitted['scale']:.2f})",
                file=sys.stderr,
            )

    if check is not None and world > 1:
        raise TrainError("checks of the training agent run in a single process, not under DDP")
    step = 0
    init_draws: dict[str, dict[str, Any]] = {}  # nets drawn again at the start (live_start); in every checkpoint
    trained_before = 0.0  # seconds of training loop in earlier attempts of this run
    if resume and os.path.exists(last_path):
        payload = read_checkpoint(last_path)
        if payload["agent"] != config.agent:
            raise TrainError(f"{last_path} is a checkpoint of agent {payload['agent']!r}, not {config.agent!r}")
        saved_recipe = payload.get("recipe", "legacy")
        if saved_recipe != config.recipe:
            raise TrainError(f"{last_path} was trained with the {saved_recipe} recipe, not {config.recipe}")
        agent.load_trainable_state_dict(payload["state_dict"])
        load_optimizer_state(optimizer, payload["trainer"]["optimizer"])  # into this device's layout and Adam
        step = int(payload["trainer"]["step"])
        trained_before = float(payload["trainer"].get("trained_s", 0.0))
        torch.set_rng_state(payload["trainer"]["torch_rng"])
        init_draws = payload.get("init_draws", {})
    if step == 0:
        agent.train()
        first = TrainingCollate(agent.config.n_rotations)([dataset.sample(0, augment=False)])
        init_draws = ensure_live(agent, agent.training_inputs(first, device), seed=config.seed * 1000 + rank)
        for name, record in init_draws.items() if rank == 0 else ():
            print(
                f"note: the {name} net's first initial weights could not learn ({record['reason']}); it "
                f"starts from draw {record['draws']} (cliport/train/live_start.py)",
                file=sys.stderr,
            )
    if rank == 0:
        os.makedirs(run.root, exist_ok=True)
        write_json(run.config, config.to_dict())

    model = None
    if world > 1:
        # DDP steps eagerly: its gradient all-reduce would need its own warm-up and stream set-up to be captured.
        ddp_ids = [local_rank] if device.type == "cuda" else None
        model = nn.parallel.DistributedDataParallel(_LossModule(agent, recipe.loss), device_ids=ddp_ids)
    graphs = config.train_graphs and world == 1
    if graphs and config.lr_cooldown > 0 and device.type in graphed_step.CAPTURE_DEVICES:
        graphs = False
        if rank == 0:
            print(
                "note: the learning-rate cooldown trains eagerly (a captured step holds its learning rate fixed)",
                file=sys.stderr,
            )
    sums = LossSums(device)
    watch = DeadMapWatch(device=device, start_step=step)
    train_step = TrainStep(
        agent,
        optimizer,
        recipe.loss,
        autocast_dtype=autocast_dtype(config, device),
        observers=(sums.add, watch.observe),
        graphs=graphs,
        compile=config.compile and world == 1,
        model=model,
        parallel_heads=config.parallel_heads and world == 1,
    )
    loader: DataLoader = training_loader(
        dataset,
        config.batch_size,
        agent.config.n_rotations,
        config.num_workers,
        seed=config.seed * 7919 + rank + step,
        pin_memory=device.type == "cuda",
        pair_contrasts=config.pair_contrasts,
    )
    schedule = set(checkpoint_schedule(config))
    fields = ["step", "loss", "pick_loss", "place_loss", "steps_per_second", "samples_per_second", "elapsed_s"]
    curve = CheckCurve(run.held_out, check.describe(), step) if check is not None and rank == 0 else None
    loop_start = time.perf_counter()

    def trained_s() -> float:
        return trained_before + time.perf_counter() - loop_start

    def out_of_time() -> bool:
        return config.time_budget_s > 0 and trained_s() >= config.time_budget_s

    def run_fraction() -> float:
        done = step / config.n_steps
        return max(done, trained_s() / config.time_budget_s) if config.time_budget_s > 0 else done

    def save(kind: int | str) -> None:
        if rank != 0:
            return
        payload = {**agent.checkpoint_payload(), "recipe": config.recipe, "init_draws": init_draws}
        if kind == "last":
            payload["trainer"] = {
                "step": step,
                "optimizer": optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
                "trained_s": round(trained_s(), 3),
            }
        save_torch(payload, run.checkpoint(kind))
        if isinstance(kind, int):  # a scheduled step, not "last"
            save_weights(payload, run.weights(kind), step=kind)  # safetensors beside the .pt
            link_or_copy(run.weights(kind), run.model_weights)  # RUN/model.safetensors: the newest one
            if validator is not None:
                validator.checkpoint_saved(kind, run.checkpoint(kind))

    tensorboard = summary_writer(run.tensorboard, purge_step=step + 1 if step else None) if rank == 0 else None
    bar = tqdm(total=config.n_steps, initial=step, desc=f"train {config.agent}", disable=not progress or rank != 0)
    start, window_start, window_steps = time.perf_counter(), time.perf_counter(), 0
    batches = _batches(loader)
    try:
        with open(run.metrics, "a", newline="") if rank == 0 else contextlib.nullcontext() as metrics_file:
            writer = csv.DictWriter(metrics_file, fieldnames=fields) if metrics_file is not None else None
            if writer is not None and metrics_file is not None and metrics_file.tell() == 0:
                writer.writeheader()
            ended_final = False

            def end_of_step(final: bool) -> None:
                """Log, check and save after ``step`` as the schedule asks (``final``: the run's last step)."""
                nonlocal window_start, window_steps, ended_final
                ended_final = final
                if window_steps and (step % config.log_every == 0 or final):
                    row: dict[str, Any] = {k: round(v, 5) for k, v in sums.read().items()}  # waits for the device
                    watch.check()
                    elapsed = time.perf_counter() - window_start
                    row.update(
                        step=step,
                        steps_per_second=round(window_steps / elapsed, 3),
                        samples_per_second=round(window_steps * config.batch_size * world / elapsed, 2),
                        elapsed_s=round(time.perf_counter() - start, 1),
                    )
                    if writer is not None and metrics_file is not None:
                        writer.writerow(row)
                        metrics_file.flush()
                    if tensorboard is not None:
                        for key in ("loss", "pick_loss", "place_loss", "samples_per_second"):
                            tensorboard.add_scalar(f"train/{key}", row[key], step)
                        tensorboard.add_scalar("train/learning_rate", optimizer.param_groups[0]["lr"], step)
                        log_gpu_memory(tensorboard, device, step)
                    bar.set_postfix(loss=f"{row['loss']:.3f}", steps_s=f"{row['steps_per_second']:.2f}")
                    window_start, window_steps = time.perf_counter(), 0
                checking = (
                    curve is not None and check is not None and (check.due(step) or final) and not curve.has(step)
                )
                scheduled = step in schedule or final
                if scheduled or checking or step % config.save_last_every == 0:
                    watch.check()  # never save a run whose map died since the last row
                if scheduled:
                    save(step)
                replaced = None
                if checking:
                    assert curve is not None and check is not None
                    previous = curve.best
                    checked, best = curve.run(check, step, agent)
                    agent.train()
                    bar.write(_check_line(checked, best))
                    if best and tensorboard is not None:
                        tensorboard.add_scalar("held_out/score", checked["score"], step)
                    if best and not scheduled:
                        save(step)
                    if best and previous is not None and previous["step"] not in schedule:
                        replaced = previous["step"]
                if scheduled or checking or step % config.save_last_every == 0:
                    save("last")
                if replaced is not None:
                    _remove_checkpoint(run, replaced)  # after last.pt: a resume from before it still finds it

            agent.train()
            while step < config.n_steps and not out_of_time():
                cooldown.apply(run_fraction())
                train_step(_next_batch(batches))
                step += 1
                sums.count()
                window_steps += 1
                bar.update(1)
                if step_hook is not None:
                    step_hook(step)
                end_of_step(step == config.n_steps or out_of_time())
            if step and not ended_final and (step == config.n_steps or out_of_time()):
                # The budget ran out during the last step's check or saves, or an earlier attempt stopped before
                # its last step was saved: finish it as the last step.
                needed = not os.path.exists(run.checkpoint(step)) or (curve is not None and not curve.has(step))
                if needed:
                    end_of_step(True)
    except KeyboardInterrupt:
        save("last")
        raise
    finally:
        bar.close()
        if tensorboard is not None:
            tensorboard.close()
    summary: dict[str, Any] = {"run_dir": run.root, "steps": step, "checkpoints": run.checkpoint_steps()}
    summary["trained_s"] = round(trained_s(), 1)
    summary["init_draws"] = init_draws
    summary["stopped_by"] = "time_budget" if step < config.n_steps else "n_steps"
    if curve is not None and curve.best is not None:
        summary["held_out"] = {"best_step": curve.best["step"], "best_score": curve.best["score"]}
    # How this process's steps ran: replays of the captured CUDA graph, eager steps (warm-up included).
    summary["step_kinds"] = {"graph_replays": train_step.replays, "eager": train_step.eager_steps}
    if train_step.failed:
        summary["step_kinds"]["capture_failed"] = train_step.failed
    if rank == 0 and validator is not None:
        summary["validation"] = validator.finish()
    if world > 1:
        dist.barrier()
    summary["rank"] = rank
    return summary


def autocast_dtype(config: TrainConfig, device: torch.device) -> torch.dtype | None:
    """The dtype a training step of ``config`` autocasts to on ``device`` (``amp``: bf16 where asked, or where
    ``auto`` finds native bf16), or None for full precision."""
    use_amp = config.amp == "bf16" or (config.amp == "auto" and bf16_native(device))
    return torch.bfloat16 if use_amp else None


def _check_line(row: dict[str, Any], best: bool) -> str:
    numbers = ", ".join(f"{k} {v}" for k, v in row.items() if k not in ("step", "score", "seconds"))
    return f"check at step {row['step']}: {numbers} ({row['seconds']:.0f} s){'; the best so far' if best else ''}"


def _remove_checkpoint(run: RunDir, step: int) -> None:
    """Delete a scheduled checkpoint a better one replaced (its .pt and .safetensors)."""
    for path in (run.checkpoint(step), run.weights(step)):
        with contextlib.suppress(FileNotFoundError):
            os.remove(path)


def load_resume_state(path: str) -> dict[str, Any]:
    """The trainer state saved in a run's ``checkpoints/last.pt`` (step, optimiser, RNG)."""
    payload = load_torch(path)
    if "trainer" not in payload:
        raise TrainError(f"{path} holds no trainer state")
    return payload["trainer"]
