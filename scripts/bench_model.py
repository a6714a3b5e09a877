"""Benchmark the agents: training samples/s, act() latency and peak memory, as JSON.

Example: python scripts/bench_model.py --agent two_stream --device cuda --amp bf16
Random inputs and random-initialised pretrained parts (CLIP, ResNet-50, DistilBERT); timings exclude one
warm-up step. `--flops` also counts the
floating-point operations of one training sample and one act() (convolutions and matrix products, as
torch.utils.flop_counter counts them; the FFT place correlation is not counted). `--profile` adds the 15
operations with the most self time (CUDA time on a GPU, CPU time on a CPU) over one training step and
one act(). `--act-batch N` times act_batch over N observations.

`--lesson` times the language lesson's training step instead (`scripts/quickstart.py --language`: two_stream at
width 0.125, map_scale 0.5, one place rotation, batches of two holding a contrasting pair, the pick and place halves
at once), as the lesson's first line probes it, `--steps` timed steps after two warm-up steps, repeated `--repeats`
times; the report gives the median and every repeat's steps per second, and the machine it ran on.
`--quickstart-args="FLAGS"` passes flags of the lesson to it; write the `=`, as `--quickstart-args=--no-scale-up-mid`
(a value that starts with "--" needs it).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shlex
import statistics
import sys
import tempfile
import time
from typing import Any

import numpy as np
import torch
from torch.profiler import ProfilerActivity, profile
from torch.utils.flop_counter import FlopCounterMode

from cliport.agents import PickPlaceAgent, agent_class, agent_names, make_agent
from cliport.agents.loss import optimizer_step
from cliport.train.step_timing import step_seconds
from cliport.utils.machine import measurement_environment

H, W = 320, 160
INSTRUCTION = "put the red blocks in a green bowl"
PROFILE_ROWS = 15
# Defaults per device type: (width, batch sizes, steps). A paper-size batch-8 two_stream step takes minutes
# on a CPU, so the CPU defaults are a quarter-width model that finishes in about a minute.
DEFAULTS = {"cuda": (1.0, [1, 8], 3), "cpu": (0.25, [1, 2], 1)}
EPILOG = (
    "Defaults: on CUDA --width 1 --batch-sizes 1 8 --steps 3 (paper size); elsewhere --width 0.25 "
    "--batch-sizes 1 2 --steps 1. Paper size on a CPU: --width 1 --batch-sizes 1 8 (minutes per two_stream step)."
)


def _batch(batch_size: int, n_rotations: int, rng: np.random.Generator) -> dict[str, Any]:
    return {
        "color": torch.from_numpy(rng.integers(0, 255, (batch_size, H, W, 3), dtype=np.uint8)),
        "height": torch.from_numpy(rng.uniform(0, 0.05, (batch_size, H, W)).astype(np.float32)),
        "pick_pix": torch.from_numpy(rng.integers(0, [H, W], (batch_size, 2))),
        "place_pix": torch.from_numpy(rng.integers(0, [H, W], (batch_size, 2))),
        "place_rot": torch.from_numpy(rng.integers(0, n_rotations, batch_size)),
        "lang": [INSTRUCTION] * batch_size,
    }


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _autocast(device: torch.device, amp: str) -> contextlib.AbstractContextManager[Any]:
    if amp == "bf16":
        return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _train_step(agent: PickPlaceAgent, optimizer: torch.optim.Optimizer, batch: dict[str, Any], amp: str) -> None:
    agent.train()
    optimizer_step(agent.compute_loss, batch, optimizer, _autocast(agent.device, amp))


def _observation(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {
        "color": rng.integers(0, 255, (H, W, 3), dtype=np.uint8),
        "height": rng.uniform(0, 0.05, (H, W)).astype(np.float32),
    }


def _act(agent: PickPlaceAgent, obs: dict[str, np.ndarray], amp: str) -> None:
    with _autocast(agent.device, amp):
        agent.act(obs, INSTRUCTION)


def _train_rate(agent: PickPlaceAgent, batch_size: int, steps: int, device: torch.device, amp: str) -> float:
    rng = np.random.default_rng(0)
    optimizer = agent.make_optimizer()
    agent.train()
    elapsed = 0.0
    for step in range(steps + 1):
        batch = _batch(batch_size, agent.config.n_rotations, rng)
        _sync(device)
        start = time.perf_counter()
        _train_step(agent, optimizer, batch, amp)
        _sync(device)
        if step > 0:
            elapsed += time.perf_counter() - start
    return steps * batch_size / elapsed


def _act_batch_latency(agent: PickPlaceAgent, n: int, repeats: int, device: torch.device, amp: str) -> float:
    rng = np.random.default_rng(3)
    observations = [_observation(rng) for _ in range(n)]
    times = []
    for i in range(repeats + 1):
        _sync(device)
        start = time.perf_counter()
        with _autocast(device, amp):
            agent.act_batch(observations, [INSTRUCTION] * n)
        _sync(device)
        if i > 0:
            times.append(time.perf_counter() - start)
    return float(np.mean(times))


def _profile(agent: PickPlaceAgent, batch_size: int, device: torch.device, amp: str) -> list[dict[str, Any]]:
    """The PROFILE_ROWS operations with the most self time over one training step and one act() (after a
    warm-up of each): device time on CUDA, CPU time elsewhere."""
    rng = np.random.default_rng(4)
    optimizer = agent.make_optimizer()
    batch = _batch(batch_size, agent.config.n_rotations, rng)
    obs = _observation(rng)
    agent.train()
    _train_step(agent, optimizer, batch, amp)
    _act(agent, obs, amp)
    cuda = device.type == "cuda"
    activities = [ProfilerActivity.CPU, ProfilerActivity.CUDA] if cuda else [ProfilerActivity.CPU]
    _sync(device)
    with profile(activities=activities) as prof:
        agent.train()
        _train_step(agent, optimizer, batch, amp)
        _act(agent, obs, amp)
        _sync(device)
    events = prof.key_averages()
    attr = "self_device_time_total" if cuda else "self_cpu_time_total"
    total = sum(max(getattr(e, attr), 0.0) for e in events)
    top = sorted(events, key=lambda e: getattr(e, attr), reverse=True)[:PROFILE_ROWS]
    return [
        {
            "op": e.key,
            "calls": e.count,
            "total_ms": getattr(e, attr) / 1e3,
            "share": getattr(e, attr) / total if total > 0 else 0.0,
        }
        for e in top
    ]


def _act_latency(agent: PickPlaceAgent, repeats: int, device: torch.device, amp: str) -> float:
    obs = _observation(np.random.default_rng(1))
    times = []
    for i in range(repeats + 1):
        _sync(device)
        start = time.perf_counter()
        _act(agent, obs, amp)
        _sync(device)
        if i > 0:
            times.append(time.perf_counter() - start)
    return float(np.mean(times))


def _gflops(agent: PickPlaceAgent, amp: str) -> dict[str, float]:
    """GFLOP of one training step at batch 1 (forward + backward) and of one act() call."""
    rng = np.random.default_rng(2)
    optimizer = agent.make_optimizer()
    agent.train()
    batch = _batch(1, agent.config.n_rotations, rng)
    with FlopCounterMode(display=False) as counter:
        _train_step(agent, optimizer, batch, amp)
    train = counter.get_total_flops()
    obs = _observation(rng)
    with FlopCounterMode(display=False) as counter:
        _act(agent, obs, amp)
    return {"train_gflop_per_sample": train / 1e9, "act_gflop": counter.get_total_flops() / 1e9}


def make_bench_agent(name: str, width: float, device: torch.device, optimize: bool = True) -> PickPlaceAgent:
    """The agent at `width` on `device`; ``optimize=False`` turns off its CUDA speed settings."""
    overrides: dict[str, Any] = {"width": width, **dict.fromkeys(agent_class(name).weight_sources, "random")}
    torch.manual_seed(0)
    agent = make_agent(name, overrides)
    if not optimize:
        agent.optimize_for_device(channels_last=False, bf16_clip=False, fused_adam=False, act_graphs=False)
    return agent.to(device)


def bench(
    name: str,
    device: torch.device,
    amp: str,
    steps: int,
    batch_sizes: list[int],
    width: float = 1.0,
    flops: bool = False,
    profile_ops: bool = False,
    act_batch: int = 0,
    optimize: bool = True,
) -> dict[str, Any]:
    """Timings (and optionally GFLOP and a profile) of agent `name`, as a JSON-ready dict."""
    agent = make_bench_agent(name, width, device, optimize)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    result: dict[str, Any] = {"act_latency_s": _act_latency(agent, steps, device, amp)}
    if act_batch:
        latency = _act_batch_latency(agent, act_batch, steps, device, amp)
        result[f"act_batch{act_batch}_latency_s"] = latency
        result[f"act_batch{act_batch}_s_per_observation"] = latency / act_batch
    for batch_size in batch_sizes:
        result[f"train_samples_per_s_batch{batch_size}"] = _train_rate(agent, batch_size, steps, device, amp)
    if device.type == "cuda":
        result["cuda_max_allocated_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
    if flops:
        result.update(_gflops(agent, amp))
    if profile_ops:
        result["profile_device"] = "cuda" if device.type == "cuda" else "cpu"
        result["profile_top_ops"] = _profile(agent, batch_sizes[0], device, amp)
    return result


def bench_lesson(device: torch.device, steps: int, repeats: int, flags: list[str] | None = None) -> dict[str, Any]:
    """Steps per second of the language lesson's training step (its configuration as scripts/quickstart.py
    --language builds it on ``device`` with ``flags``, random CLIP weights), ``repeats`` times ``steps`` steps."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import quickstart  # noqa: PLC0415 - the lesson's configuration lives in the script beside this one

    args = quickstart.parse_args(device.type, ["--language", *(flags or [])])
    with tempfile.TemporaryDirectory() as tmp:
        config = quickstart.train_config(args, tmp, os.path.join(tmp, "run"), "random", check_saved=False)
        rates = [1.0 / step_seconds(config, steps=steps) for _ in range(repeats)]
    agent_config = config.agent_config
    return {
        "agent": config.agent,
        "width": agent_config.width,
        "map_scale": agent_config.map_scale,
        "n_rotations": agent_config.n_rotations,
        "batch_size": config.batch_size,
        "pair_contrasts": config.pair_contrasts,
        "parallel_heads": config.parallel_heads,
        "scale_up_mid": getattr(agent_config, "scale_up_mid", None),
        "quickstart_args": flags or [],
        "steps_per_repeat": steps,
        "train_steps_per_s": statistics.median(rates),
        "train_steps_per_s_repeats": rates,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=EPILOG)
    parser.add_argument("--agent", choices=[*agent_names(), "all"], default="all", help="an agent, or all of them")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--amp", choices=["none", "bf16"], default="none", help="autocast dtype")
    parser.add_argument("--steps", type=int, help="timed steps / act calls after one warm-up (CUDA 3, CPU 1)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", help="training batch sizes (CUDA 1 8, CPU 1 2)")
    parser.add_argument("--width", type=float, help="channel-width multiplier, 1.0 = paper size (CUDA 1, CPU 0.25)")
    parser.add_argument("--flops", action="store_true", help="also count GFLOP per training sample and per act()")
    parser.add_argument("--profile", action="store_true", help=f"add the top {PROFILE_ROWS} operations by self time")
    parser.add_argument("--act-batch", type=int, default=0, metavar="N", help="also time act_batch over N observations")
    parser.add_argument(
        "--no-optimize", action="store_true", help="turn off the CUDA speed settings (channels_last, bf16 CLIP, ...)"
    )
    parser.add_argument(
        "--lesson", action="store_true", help="time the language lesson's training step instead (see the docstring)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="with --lesson: how many times to time --steps steps")
    parser.add_argument(
        "--quickstart-args",
        default="",
        metavar="FLAGS",
        help='with --lesson: flags of the lesson, e.g. --quickstart-args="--seed 1"',
    )
    args = parser.parse_args()
    device = torch.device(args.device)
    if args.lesson:
        steps = 4 if args.steps is None else args.steps
        if steps < 1 or args.repeats < 1:
            parser.error("--steps and --repeats must be >= 1")
        flags = shlex.split(args.quickstart_args)
        lesson = {"lesson": bench_lesson(device, steps, args.repeats, flags), "clip_weights": "random"}
        print(json.dumps({**lesson, "environment": measurement_environment()}, indent=2))
        return
    width, batch_sizes, steps = DEFAULTS["cuda" if device.type == "cuda" else "cpu"]
    args.width = width if args.width is None else args.width
    args.batch_sizes = batch_sizes if args.batch_sizes is None else args.batch_sizes
    args.steps = steps if args.steps is None else args.steps
    if args.steps < 1 or args.width <= 0 or min(args.batch_sizes) < 1 or args.act_batch < 0:
        parser.error("--steps and --batch-sizes must be >= 1, --act-batch >= 0 and --width > 0")
    names = agent_names() if args.agent == "all" else [args.agent]
    report: dict[str, Any] = {
        "environment": measurement_environment(),
        "device": str(device) if device.type != "cuda" else torch.cuda.get_device_name(device),
        "torch_threads": torch.get_num_threads(),
        "amp": args.amp,
        "clip_weights": "random",
        "pretrained_weights": "random (every pretrained part: CLIP, ResNet-50, DistilBERT)",
        "width": args.width,
        "batch_sizes": args.batch_sizes,
        "steps": args.steps,
        "optimize_for_device": not args.no_optimize,
    }
    for name in names:
        report[name] = bench(
            name,
            device,
            args.amp,
            args.steps,
            args.batch_sizes,
            args.width,
            args.flops,
            args.profile,
            args.act_batch,
            not args.no_optimize,
        )
    # ru_maxrss is in KiB on Linux; it is the peak of the whole process (all agents benchmarked).
    report["cpu_peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
