"""Benchmark cliport-train's own loop (loader, step and logging) and act(), beside the reference's released code.

For each agent and batch size it runs ``cliport.train.trainer.train`` (the loop ``cliport-train`` runs: worker
processes augmenting demos, the captured or eager step, metrics rows) on demos written for the run (random images,
the quickstart's task) and reads the rate from metrics.csv, the first window (start-up, warm-up, capture) left out.
It also times act() (``scripts/bench_model.py``'s timing) and the loader alone at batch 1. With
``--reference-dir`` (the reference CLIPort folder, e.g. ../shared/reference-cliport) it runs that folder's
``ref_bench.py`` on the same device in a subprocess (the released training step and act() at batch 1, published
size) and prints our figures over the reference's. ``--profile`` adds the top operations by self time (device time
on CUDA) of a separate short run of each profiled configuration. Prints one JSON object (``--out`` also writes it
there, and FILE.partial after each measurement while the run goes on).

Published size on a GPU (defaults there: width 1, batch sizes 1 and 8, 100 timed steps in windows of 20):
    python scripts/bench_train.py --reference-dir ../shared/reference-cliport
Tiny, on a CPU (defaults there: width 0.125, batch size 1, 4 timed steps in windows of 2, 8 rotations):
    python scripts/bench_train.py --agents transporter_only
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench_model  # noqa: E402 - the act() timing is bench_model's

from cliport.agents import agent_class, agent_names  # noqa: E402
from cliport.data.dataset import DemoDataset  # noqa: E402
from cliport.data.episode_io import dataset_dir, episode_path, save_episode  # noqa: E402
from cliport.env.transforms import yaw_to_quat  # noqa: E402
from cliport.train.config import TrainConfig  # noqa: E402
from cliport.train.loader import training_loader  # noqa: E402
from cliport.train.recipes import get_recipe  # noqa: E402
from cliport.train.trainer import train  # noqa: E402
from cliport.utils.machine import measurement_environment

TASK = "place-red-in-green"
INSTRUCTION = "put the red blocks in a green bowl"
PROFILE_ROWS = 15
#: Our agent -> the reference's (ref_bench.py's names).
REFERENCE_AGENTS = {"transporter_only": "transporter", "two_stream": "cliport"}
#: Per device type: width, batch sizes, timed steps, log window, place rotations.
DEFAULTS = {"cuda": (1.0, [1, 8], 100, 20, 36), "cpu": (0.125, [1], 4, 2, 8)}


def write_demos(root: str, n_episodes: int, steps: int = 2, seed: int = 0) -> str:
    """``n_episodes`` episodes of the quickstart's task with random images and in-bounds poses (what the loader
    reads and augments; their content does not change the work) under ``root``; returns ``root``."""
    folder = dataset_dir(root, TASK, "train")
    os.makedirs(folder, exist_ok=True)
    rng = np.random.default_rng(seed)
    for e in range(n_episodes):
        episode = []
        for _ in range(steps):
            xy = rng.uniform([0.35, -0.35], [0.65, 0.35], size=(2, 2))
            episode.append(
                {
                    "obs": {
                        "color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8),
                        "height": rng.uniform(0, 0.05, (320, 160)).astype(np.float32),
                    },
                    "action": {
                        "pose0": ((*xy[0], 0.02), yaw_to_quat(float(rng.uniform(-3, 3)))),
                        "pose1": ((*xy[1], 0.02), yaw_to_quat(float(rng.uniform(-3, 3)))),
                    },
                    "reward": 1.0 / steps,
                    "lang_goal": INSTRUCTION,
                }
            )
        save_episode(episode_path(folder, e), episode, {"task": TASK, "seed": e})
    return root


def _config(args: argparse.Namespace, agent: str, batch_size: int, n_steps: int, data_dir: str, run_dir: str):
    agent_config: dict[str, Any] = {"width": args.width, "n_rotations": args.n_rotations, "crop_size": args.crop_size}
    agent_config.update(dict.fromkeys(agent_class(agent).weight_sources, "random"))
    return TrainConfig.build(
        {
            "agent": agent,
            "task": TASK,
            "recipe": args.recipe,
            "n_demos": args.n_demos,
            "n_steps": n_steps,
            "batch_size": batch_size,
            "data_dir": data_dir,
            "run_dir": run_dir,
            "device": args.device,
            "num_workers": args.num_workers,
            "amp": args.amp,
            "checkpoint_steps": [],
            "checkpoint_every": 0,
            "save_last_every": n_steps + 1,
            "log_every": args.log_every,
            "val_episodes": 0,
            "train_graphs": args.train_graphs,
            "compile": args.compile,
            "agent_config": agent_config,
        }
    )


def _rows(run_dir: str) -> list[dict[str, float]]:
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        header, *lines = f.read().split()
    keys = header.split(",")
    return [dict(zip(keys, map(float, line.split(",")), strict=True)) for line in lines]


def _device(args: argparse.Namespace) -> torch.device:
    return torch.device(args.device)


def time_training(args: argparse.Namespace, agent: str, batch_size: int, data_dir: str, root: str) -> dict[str, Any]:
    """The loop's rate over the windows after the first, and what ran: graph replays and eager steps."""
    windows = -(-args.steps // args.log_every)
    run_dir = os.path.join(root, f"{agent}-b{batch_size}")
    device = _device(args)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    summary = train(_config(args, agent, batch_size, (1 + windows) * args.log_every, data_dir, run_dir), progress=False)
    rows = _rows(run_dir)[1:]
    seconds = sum(args.log_every / row["steps_per_second"] for row in rows)
    steps = len(rows) * args.log_every
    out: dict[str, Any] = {
        "steps_per_s": steps / seconds,
        "samples_per_s": steps * batch_size / seconds,
        "timed_steps": steps,
        "step_kinds": summary["step_kinds"],
        "last_loss": rows[-1]["loss"],
    }
    if device.type == "cuda":
        out["cuda_max_allocated_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
        out["cuda_max_reserved_gib"] = torch.cuda.max_memory_reserved(device) / 2**30
    return out


def profile_training(args: argparse.Namespace, agent: str, batch_size: int, data_dir: str, root: str) -> dict[str, Any]:
    """The top operations by self time over ``min(10, steps)`` steps after the first window of a separate run."""
    from torch.profiler import ProfilerActivity, profile, schedule

    device = _device(args)
    cuda = device.type == "cuda"
    active = min(10, args.steps)
    activities = [ProfilerActivity.CPU, ProfilerActivity.CUDA] if cuda else [ProfilerActivity.CPU]
    run_dir = os.path.join(root, f"profile-{agent}-b{batch_size}")
    n_steps = args.log_every + active + 1
    with profile(
        activities=activities, schedule=schedule(wait=args.log_every - 1, warmup=1, active=active, repeat=1)
    ) as prof:
        train(
            _config(args, agent, batch_size, n_steps, data_dir, run_dir),
            progress=False,
            step_hook=lambda _: prof.step(),
        )
    events = prof.key_averages()
    attr = "self_device_time_total" if cuda else "self_cpu_time_total"
    total = sum(max(getattr(e, attr), 0.0) for e in events)
    top = sorted(events, key=lambda e: getattr(e, attr), reverse=True)[:PROFILE_ROWS]
    return {
        "device": "cuda" if cuda else "cpu",
        "steps": active,
        "top_ops": [
            {
                "op": e.key,
                "calls": e.count,
                "ms_per_step": getattr(e, attr) / 1e3 / active,
                "share": getattr(e, attr) / total,
            }
            for e in top
            if total > 0
        ],
    }


def time_loader(args: argparse.Namespace, data_dir: str, batches: int = 200) -> dict[str, Any]:
    """Samples/s the trainer's loader serves alone at batch 1 (after its first batch), as configured."""
    recipe = get_recipe(args.recipe)
    dataset = DemoDataset(
        data_dir, TASK, "train", args.n_demos, aug_pivot=recipe.aug_pivot, aug_interpolation=recipe.aug_interpolation
    )
    loader = training_loader(
        dataset, 1, args.n_rotations, args.num_workers, seed=0, pin_memory=_device(args).type == "cuda"
    )
    it = iter(loader)
    next(it)
    start = time.perf_counter()
    for _ in range(batches):
        next(it)
    rate = batches / (time.perf_counter() - start)
    del it, loader
    return {"samples_per_s": rate, "batch_size": 1, "num_workers": args.num_workers, "batches": batches}


def time_act(args: argparse.Namespace, agent: str) -> dict[str, Any]:
    device = _device(args)
    model = bench_model.make_bench_agent(agent, args.width, device)  # 36 rotations, 64-pixel crops
    latency = bench_model._act_latency(model, args.act_repeats, device, "none")
    del model
    return {"act_ms": latency * 1e3, "repeats": args.act_repeats}


def run_reference(args: argparse.Namespace, agents: list[str]) -> dict[str, Any]:
    """ref_bench.py of the reference folder on the same device, in a subprocess (it must not import this project's
    own ``cliport`` package); its JSON per reference agent, or why it did not run."""
    script = os.path.join(args.reference_dir, "ref_bench.py")
    if not os.path.isfile(script):
        return {"error": f"no ref_bench.py in {args.reference_dir}"}
    names = sorted({REFERENCE_AGENTS[a] for a in agents if a in REFERENCE_AGENTS})
    if not names:
        return {"error": "none of the benchmarked agents has a reference counterpart"}
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "ref.json")
        command = [
            sys.executable,
            script,
            "--device",
            _device(args).type,
            "--steps",
            str(args.reference_steps),
            "--out",
            out,
        ]
        command += ["--agent", names[0] if len(names) == 1 else "both"]
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"PYTHONPATH": _reference_path(args)}
        start = time.perf_counter()
        done = subprocess.run(command, cwd=args.reference_dir, capture_output=True, text=True, env=env)
        if done.returncode != 0 or not os.path.exists(out):
            return {"error": f"ref_bench.py exited with {done.returncode}: {done.stderr.strip()[-1500:]}"}
        with open(out) as f:
            result = json.load(f)
    keep = (
        "train_step_s",
        "train_samples_per_s",
        "act_s",
        "train_peak_mem_gib",
        "act_peak_mem_gib",
        "params_trainable",
    )
    report: dict[str, Any] = {"seconds": time.perf_counter() - start, "command": " ".join(command[1:])}
    for name, values in result.items():
        report[name] = {k: values.get(k) for k in keep if k in values}
        report["env"] = values.get("env")
    return report


def _reference_path(args: argparse.Namespace) -> str:
    # ref_bench.py puts its own folder and stubs first; the packages it needs (torch, numpy, ...) come from
    # PYTHONPATH entries that are not this project's checkout (packages installed with pip --target, say).
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    kept = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and os.path.abspath(p) != root]
    return os.pathsep.join([args.reference_dir, os.path.join(args.reference_dir, "stubs"), *kept])


def ratios(report: dict[str, Any], reference: dict[str, Any]) -> dict[str, Any]:
    """Ours over the reference's: batch-1 training samples/s, and act() speed (reference time / ours)."""
    out: dict[str, Any] = {}
    for agent, ref_name in REFERENCE_AGENTS.items():
        ours, ref = report.get("agents", {}).get(agent), reference.get(ref_name)
        if not ours or not ref:
            continue
        row: dict[str, Any] = {}
        batch1 = ours.get("train", {}).get("batch1")
        if batch1 and ref.get("train_samples_per_s"):
            row["train_batch1"] = batch1["samples_per_s"] / ref["train_samples_per_s"]
        if ours.get("act") and ref.get("act_s"):
            row["act"] = ref["act_s"] * 1e3 / ours["act"]["act_ms"]
        out[agent] = row
    return out


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", nargs="+", choices=agent_names(), default=["transporter_only", "two_stream"])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--width", type=float, help="channel-width multiplier (CUDA 1, the published size; CPU 0.125)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", help="training batch sizes (CUDA 1 8; CPU 1)")
    parser.add_argument("--steps", type=int, help="timed training steps per configuration (CUDA 100; CPU 4)")
    parser.add_argument(
        "--log-every", type=int, help="steps per metrics row; the first row is left out (CUDA 20; CPU 2)"
    )
    parser.add_argument("--n-rotations", type=int, help="place rotations (CUDA 36, the published count; CPU 8)")
    parser.add_argument("--crop-size", type=int, default=64)
    parser.add_argument("--recipe", default="cliport", help="training recipe (the reference's code: cliport)")
    parser.add_argument("--amp", choices=["auto", "bf16", "none"], default="auto", help="as cliport-train's --amp")
    parser.add_argument("--train-graphs", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--compile", action=argparse.BooleanOptionalAction, default=False)
    parser.add_argument("--num-workers", type=int, default=2, help="loader worker processes (cliport-train's default)")
    parser.add_argument("--n-demos", type=int, default=10, help="demos written for the runs")
    parser.add_argument("--act-repeats", type=int, default=10)
    parser.add_argument("--no-act", action="store_true", help="skip the act() timing")
    parser.add_argument("--reference-dir", help="the reference CLIPort folder holding ref_bench.py")
    parser.add_argument("--reference-steps", type=int, default=10, help="ref_bench.py's --steps")
    parser.add_argument(
        "--profile", action="store_true", help=f"add the top {PROFILE_ROWS} operations per profiled run"
    )
    parser.add_argument(
        "--profile-batch-sizes", type=int, nargs="+", help="batch sizes to profile (default: the first)"
    )
    parser.add_argument("--out", help="also write the JSON here")
    return parser


def main() -> None:
    parser = _parser()
    args = parser.parse_args()
    try:
        device = torch.device(args.device)
    except RuntimeError:
        parser.error(f"--device: unknown device {args.device!r}")
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: CUDA is not available")
    width, batch_sizes, steps, log_every, n_rotations = DEFAULTS["cuda" if device.type == "cuda" else "cpu"]
    args.width = width if args.width is None else args.width
    args.batch_sizes = batch_sizes if args.batch_sizes is None else args.batch_sizes
    args.steps = steps if args.steps is None else args.steps
    args.log_every = log_every if args.log_every is None else args.log_every
    args.n_rotations = n_rotations if args.n_rotations is None else args.n_rotations
    args.profile_batch_sizes = args.profile_batch_sizes or args.batch_sizes[:1]
    if args.width <= 0 or min(args.batch_sizes) < 1 or args.steps < 1 or args.log_every < 1 or args.n_demos < 1:
        parser.error("--width must be > 0 and --batch-sizes, --steps, --log-every and --n-demos >= 1")
    if args.reference_dir and not os.path.isfile(os.path.join(args.reference_dir, "ref_bench.py")):
        parser.error(f"--reference-dir: no ref_bench.py in {args.reference_dir}")
    report: dict[str, Any] = {
        "device": str(device) if device.type != "cuda" else torch.cuda.get_device_name(device),
        "torch": torch.__version__,
        "cpu_count": os.cpu_count(),
        "width": args.width,
        "n_rotations": args.n_rotations,
        "recipe": args.recipe,
        "amp": args.amp,
        "train_graphs": args.train_graphs,
        "compile": args.compile,
        "num_workers": args.num_workers,
        "timed_steps": args.steps,
        "log_every": args.log_every,
        "pretrained_weights": "random",
        "agents": {},
    }
    partial = f"{args.out}.partial" if args.out else None
    with tempfile.TemporaryDirectory(prefix="cliport-bench-train-") as root:
        data_dir = write_demos(os.path.join(root, "data"), args.n_demos)
        report["loader"] = time_loader(args, data_dir)
        _write(report, partial)
        for agent in args.agents:
            result: dict[str, Any] = {"train": {}}
            for batch_size in args.batch_sizes:
                result["train"][f"batch{batch_size}"] = time_training(args, agent, batch_size, data_dir, root)
                report["agents"][agent] = result
                _write(report, partial)
                gc.collect()
                if device.type == "cuda":
                    torch.cuda.empty_cache()
            if not args.no_act:
                result["act"] = time_act(args, agent)
            if args.profile:
                result["profile"] = {
                    f"batch{b}": profile_training(args, agent, b, data_dir, root) for b in args.profile_batch_sizes
                }
            report["agents"][agent] = result
            _write(report, partial)
            gc.collect()
            if device.type == "cuda":
                torch.cuda.empty_cache()
    if args.reference_dir:
        reference = run_reference(args, args.agents)
        report["reference"] = reference
        report["ratio_to_reference"] = ratios(report, reference)
        report["ratio_note"] = "ours / the reference's at batch 1 (train samples/s) and reference act time / ours" + (
            "" if args.width == 1.0 else f"; ours ran at width {args.width}, the reference at the published size"
        )
    report["environment"] = measurement_environment()
    _write(report, args.out)
    if partial:
        with contextlib.suppress(OSError):
            os.remove(partial)
    print(json.dumps(report, indent=2))


def _write(report: dict[str, Any], path: str | None) -> None:
    """Write the report atomically (``--out``; ``--out``.partial after each measurement, so that a run cut short
    keeps what it measured)."""
    if not path:
        return
    with open(f"{path}.tmp", "w") as f:
        f.write(json.dumps(report, indent=2) + "\n")
    os.replace(f"{path}.tmp", path)


if __name__ == "__main__":
    main()
