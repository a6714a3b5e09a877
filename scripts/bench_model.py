"""Benchmark the agents: training samples/s (batch 1 and 8), act() latency and peak memory, as JSON.

Example: python scripts/bench_model.py --agent two_stream --device cuda --amp bf16
Random inputs and random-initialised CLIP; timings exclude one warm-up step. `--flops` also counts the
floating-point operations of one training sample and one act() (convolutions and matrix products, as
torch.utils.flop_counter counts them; the FFT place correlation is not counted).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import time
from typing import Any

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from cliport.agents import PickPlaceAgent, make_agent

H, W = 320, 160
INSTRUCTION = "put the red blocks in a green bowl"


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
    optimizer.zero_grad(set_to_none=True)
    with _autocast(agent.device, amp):
        loss, _ = agent.compute_loss(batch)
    loss.backward()
    optimizer.step()


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


def make_bench_agent(name: str, width: float, device: torch.device) -> PickPlaceAgent:
    overrides: dict[str, Any] = {"width": width}
    if name == "two_stream":
        overrides["clip_weights"] = "random"
    torch.manual_seed(0)
    return make_agent(name, overrides).to(device)


def bench(
    name: str,
    device: torch.device,
    amp: str,
    steps: int,
    batch_sizes: list[int],
    width: float = 1.0,
    flops: bool = False,
) -> dict[str, Any]:
    agent = make_bench_agent(name, width, device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    result: dict[str, Any] = {"act_latency_s": _act_latency(agent, steps, device, amp)}
    for batch_size in batch_sizes:
        result[f"train_samples_per_s_batch{batch_size}"] = _train_rate(agent, batch_size, steps, device, amp)
    if device.type == "cuda":
        result["cuda_max_allocated_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
    if flops:
        result.update(_gflops(agent, amp))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", choices=["transporter_only", "two_stream", "both"], default="both")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--amp", choices=["none", "bf16"], default="none")
    parser.add_argument("--steps", type=int, default=3, help="timed steps / act calls (after one warm-up)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--width", type=float, default=1.0, help="channel-width multiplier (1.0 = paper size)")
    parser.add_argument("--flops", action="store_true", help="also count GFLOP per training sample and per act()")
    args = parser.parse_args()
    if args.steps < 1 or args.width <= 0 or min(args.batch_sizes) < 1:
        parser.error("--steps and --batch-sizes must be >= 1 and --width > 0")
    device = torch.device(args.device)
    names = ["transporter_only", "two_stream"] if args.agent == "both" else [args.agent]
    report: dict[str, Any] = {
        "device": str(device) if device.type != "cuda" else torch.cuda.get_device_name(device),
        "torch_threads": torch.get_num_threads(),
        "amp": args.amp,
        "clip_weights": "random",
        "width": args.width,
    }
    for name in names:
        report[name] = bench(name, device, args.amp, args.steps, args.batch_sizes, args.width, args.flops)
    # ru_maxrss is in KiB on Linux; it is the peak of the whole process (all agents benchmarked).
    report["cpu_peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
