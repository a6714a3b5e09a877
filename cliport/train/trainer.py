"""Training: a step loop over augmented demonstration batches with scheduled checkpoints, a rolling
resume point, metrics, optional DDP (torchrun) and mixed precision, then validation by task success.

Run folder layout::

    RUN/config.json             the resolved TrainConfig
    RUN/metrics.csv             step, losses, throughput (and RUN/tensorboard/ when tensorboard is installed)
    RUN/checkpoints/step-001000.pt ...   scheduled checkpoints (agent weights + config)
    RUN/checkpoints/last.pt     rolling resume point (also holds the optimiser and step)
    RUN/val.json                validation success of every scheduled checkpoint and the best one
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import re
import time
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, RandomSampler
from tqdm import tqdm

from cliport.utils.config import build, read_defaults


@dataclass
class TrainConfig:
    agent: str
    n_demos: int
    n_steps: int
    batch_size: int
    data_dir: str
    device: str
    seed: int
    num_workers: int
    amp: str
    checkpoint_steps: list[int]
    checkpoint_every: int
    save_last_every: int
    log_every: int
    val_episodes: int
    camera_scale: float
    task: str = ""
    run_dir: str | None = None
    lr: float | None = None
    clip_weights: str | None = None
    agent_overrides: dict[str, Any] = field(default_factory=dict)  # e.g. {"width": 0.25} for tiny nets

    @classmethod
    def defaults(cls, **overrides: Any) -> TrainConfig:
        return build(cls, read_defaults("train"), **overrides)

    def resolved_run_dir(self) -> str:
        return self.run_dir or os.path.join("runs", f"{self.task}-{self.agent}-n{self.n_demos}-s{self.seed}")


class TrainError(ValueError):
    """A training run cannot start or resume as asked; the message says why."""


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


def checkpoint_file(run_dir: str, step: int | str) -> str:
    name = "last.pt" if step == "last" else f"step-{int(step):06d}.pt"
    return os.path.join(run_dir, "checkpoints", name)


def saved_checkpoint_steps(run_dir: str) -> list[int]:
    folder = os.path.join(run_dir, "checkpoints")
    if not os.path.isdir(folder):
        return []
    return sorted(int(m.group(1)) for f in os.listdir(folder) if (m := re.fullmatch(r"step-(\d{6})\.pt", f)))


def _atomic_torch_save(obj: Any, path: str) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.tmp-{os.getpid()}"
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _write_json(path: str, data: Any) -> None:
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2)
    os.replace(tmp, path)


class _LossModule(nn.Module):
    """Wraps an agent so that DDP sees ``forward(batch) -> (loss, info)``."""

    def __init__(self, agent: nn.Module):
        super().__init__()
        self.agent = agent

    def forward(self, batch: dict[str, Any]) -> tuple[torch.Tensor, dict[str, float]]:
        return self.agent.compute_loss(batch)


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


def _tensorboard_writer(path: str):
    """A TensorBoard SummaryWriter when the tensorboard package is installed, else None (CSV only)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(path)


def _batches(loader: DataLoader):
    while True:
        yield from loader


def load_run_config(run_dir: str) -> TrainConfig:
    path = os.path.join(run_dir, "config.json")
    if not os.path.exists(path):
        raise TrainError(f"{run_dir} is not a training run (no config.json)")
    with open(path) as f:
        data = json.load(f)
    return TrainConfig(**data)


def train(config: TrainConfig, resume: bool = False, progress: bool = True) -> dict[str, Any]:
    """Train (or resume) a run; returns a summary. Validation runs afterwards when val_episodes > 0."""
    from cliport.agents import make_agent
    from cliport.data.dataset import DemoDataset
    from cliport.evaluation.evaluate import resolve_device

    rank, world, local_rank = _distributed()
    run_dir = config.resolved_run_dir()
    last_path = checkpoint_file(run_dir, "last")
    if not resume and os.path.exists(os.path.join(run_dir, "config.json")):
        raise TrainError(f"run folder {run_dir} already holds a run: pass --resume to continue it, or choose --run-dir")
    if resume and not os.path.exists(last_path):
        raise TrainError(f"nothing to resume in {run_dir}: no checkpoints/last.pt")
    if world > 1:
        dist.barrier()  # every rank has checked the run folder before rank 0 writes into it
    device = resolve_device(config.device)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", local_rank)
    torch.manual_seed(config.seed * 1000 + rank)

    overrides = dict(config.agent_overrides)
    if config.lr is not None:
        overrides["lr"] = config.lr
    if config.clip_weights is not None and config.agent == "two_stream":
        overrides["clip_weights"] = config.clip_weights
    agent = make_agent(config.agent, overrides).to(device)
    n_rotations = agent.config.n_rotations
    dataset = DemoDataset(
        config.data_dir, config.task, "train", config.n_demos, seed=config.seed, n_rotations=n_rotations
    )
    optimizer = agent.make_optimizer()

    step = 0
    if resume:
        payload = torch.load(last_path, map_location="cpu", weights_only=False)
        if payload["agent"] != config.agent:
            raise TrainError(f"{last_path} is a checkpoint of agent {payload['agent']!r}, not {config.agent!r}")
        agent.load_trainable_state_dict(payload["state_dict"])
        optimizer.load_state_dict(payload["trainer"]["optimizer"])
        step = int(payload["trainer"]["step"])
        torch.set_rng_state(payload["trainer"]["torch_rng"])
    if rank == 0:
        os.makedirs(run_dir, exist_ok=True)
        _write_json(os.path.join(run_dir, "config.json"), dataclasses.asdict(config))

    model: nn.Module = _LossModule(agent)
    if world > 1:
        model = nn.parallel.DistributedDataParallel(model, device_ids=[local_rank] if device.type == "cuda" else None)
    use_amp = config.amp == "bf16" or (config.amp == "auto" and device.type == "cuda")
    autocast = torch.autocast(device.type, dtype=torch.bfloat16) if use_amp else contextlib.nullcontext()

    generator = torch.Generator().manual_seed(config.seed * 7919 + rank + step)
    sampler = RandomSampler(dataset, replacement=True, num_samples=10**9, generator=generator)
    loader = DataLoader(
        dataset,
        batch_size=config.batch_size,
        sampler=sampler,
        num_workers=config.num_workers,
        persistent_workers=config.num_workers > 0,
        pin_memory=device.type == "cuda",
        drop_last=True,
    )
    schedule = set(checkpoint_schedule(config))
    metrics_path = os.path.join(run_dir, "metrics.csv")
    fields = ["step", "loss", "pick_loss", "place_loss", "steps_per_second", "samples_per_second", "elapsed_s"]

    def save(kind: int | str) -> None:
        if rank != 0:
            return
        payload = agent.checkpoint_payload()
        if kind == "last":
            payload["trainer"] = {
                "step": step,
                "optimizer": optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
            }
        _atomic_torch_save(payload, checkpoint_file(run_dir, kind))

    tensorboard = _tensorboard_writer(os.path.join(run_dir, "tensorboard")) if rank == 0 else None
    bar = tqdm(total=config.n_steps, initial=step, desc=f"train {config.agent}", disable=not progress or rank != 0)
    start, window_start, window_steps = time.perf_counter(), time.perf_counter(), 0
    sums = {"loss": 0.0, "pick_loss": 0.0, "place_loss": 0.0}
    batches = _batches(loader)
    try:
        with open(metrics_path, "a", newline="") if rank == 0 else contextlib.nullcontext() as metrics_file:
            writer = csv.DictWriter(metrics_file, fieldnames=fields) if rank == 0 else None
            if writer is not None and metrics_file.tell() == 0:
                writer.writeheader()
            agent.train()
            while step < config.n_steps:
                batch = next(batches)
                optimizer.zero_grad(set_to_none=True)
                with autocast:
                    loss, info = model(batch)
                loss.backward()
                optimizer.step()
                step += 1
                window_steps += 1
                for k in sums:
                    sums[k] += info[k]
                bar.update(1)
                if step % config.log_every == 0 or step == config.n_steps:
                    elapsed = time.perf_counter() - window_start
                    row = {k: round(v / window_steps, 5) for k, v in sums.items()}
                    row.update(
                        step=step,
                        steps_per_second=round(window_steps / elapsed, 3),
                        samples_per_second=round(window_steps * config.batch_size * world / elapsed, 2),
                        elapsed_s=round(time.perf_counter() - start, 1),
                    )
                    if writer is not None:
                        writer.writerow(row)
                        metrics_file.flush()
                    if tensorboard is not None:
                        for key in ("loss", "pick_loss", "place_loss", "samples_per_second"):
                            tensorboard.add_scalar(f"train/{key}", row[key], step)
                    bar.set_postfix(loss=f"{row['loss']:.3f}", steps_s=f"{row['steps_per_second']:.2f}")
                    sums = dict.fromkeys(sums, 0.0)
                    window_start, window_steps = time.perf_counter(), 0
                if step in schedule:
                    save(step)
                if step in schedule or step % config.save_last_every == 0:
                    save("last")
    except KeyboardInterrupt:
        save("last")
        raise
    finally:
        bar.close()
        if tensorboard is not None:
            tensorboard.close()
    summary: dict[str, Any] = {"run_dir": run_dir, "steps": step, "checkpoints": saved_checkpoint_steps(run_dir)}
    if rank == 0 and config.val_episodes > 0:
        summary["validation"] = validate(run_dir, config, device=device, progress=progress)
    if world > 1:
        dist.barrier()
    return summary


def validate(run_dir: str, config: TrainConfig, device: torch.device | None = None, progress: bool = True) -> dict:
    """Evaluate every saved checkpoint on the val episodes (resumable) and record the best in val.json."""
    from cliport.agents import load_agent
    from cliport.evaluation.evaluate import evaluate, resolve_device

    device = device or resolve_device(config.device)
    path = os.path.join(run_dir, "val.json")
    results: dict[str, Any] = {"task": config.task, "n_episodes": config.val_episodes, "checkpoints": {}}
    if os.path.exists(path):
        with open(path) as f:
            previous = json.load(f)
        if previous.get("n_episodes") == config.val_episodes:
            results = previous
    for step in saved_checkpoint_steps(run_dir):
        if str(step) in results["checkpoints"]:
            continue
        agent = load_agent(checkpoint_file(run_dir, step), device=device, clip_weights=config.clip_weights)
        scores = []
        for task in _tasks_of(config.task):
            r = evaluate(agent, task, "val", config.val_episodes, config.camera_scale, progress=progress)
            scores.append(r["mean_score"])
        results["checkpoints"][str(step)] = {"mean_score": round(sum(scores) / len(scores), 2), "per_task": scores}
        best = max(results["checkpoints"].items(), key=lambda kv: (kv[1]["mean_score"], -int(kv[0])))
        results["best_step"], results["best_score"] = int(best[0]), best[1]["mean_score"]
        _write_json(path, results)
    return results


def _tasks_of(name: str) -> list[str]:
    from cliport import tasks

    return tasks.resolve(name)
