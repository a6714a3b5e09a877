"""Acting on real observations: how often an action changes with its batch-mates' number, with bf16 and with
CUDA graphs, and (on CUDA) act-graph memory against the number of evaluation workers, as JSON.

Usage: python scripts/bench_act.py --device cuda [--checkpoint runs/R/checkpoints/step-040000.pt]
       python scripts/bench_act.py --device cpu --agent transporter_only --width 0.125
Observations are the first frames of val episodes of a few tasks, rendered with TinyRenderer at
``--camera-scale``. Without ``--checkpoint`` the agent has random weights (and random pretrained parts):
its heatmaps are nearly flat, so many of its argmax changes are between near-equal pixels; the report
counts those apart (``near_ties``: the other choice is within 0.1 % of the reference map's peak).

An action is (pick pixel, place pixel, place rotation). ``batch_size_agreement`` acts on each observation
alone and inside batches of k (k in ``--sizes``, with other observations as batch-mates);
``graphs_vs_eager`` and ``fp32_vs_bf16`` compare batch-1 actions with the setting on and off (CUDA only);
``graph_memory`` acts with an engine's batch sizes 1..N for each worker count N on a fresh agent and reports
the memory the graphs hold, and what is left after the agent is dropped without ``gc.collect()``.
"""

from __future__ import annotations

import argparse
import gc
import json
from typing import Any

import numpy as np
import torch

from cliport.agents import PickPlaceAgent, agent_class, agent_names, make_agent
from cliport.utils.machine import measurement_environment

NEAR_TIE = 1e-3
DEFAULT_TASKS = [
    "block-insertion",
    "put-block-in-bowl-seen-colors",
    "packing-shapes",
    "stack-block-pyramid-seq-seen-colors",
]


def observations(task_names: list[str], n_seeds: int, camera_scale: float) -> list[tuple[dict, str | None]]:
    """(observation, instruction) of the first frame of the first ``n_seeds`` val episodes of each task."""
    from cliport import tasks
    from cliport.data.seeds import episode_seeds
    from cliport.env.environment import EnvConfig, Environment

    out = []
    for name in task_names:
        config = EnvConfig.defaults(camera_scale=camera_scale, renderer="cpu")
        with Environment(config, task=tasks.make(name, "val")) as env:
            for seed in episode_seeds("val", n_seeds):
                obs = env.reset(seed)
                out.append(({"color": obs["color"], "height": obs["height"]}, env.lang_goal))
    return out


def _decision(result: dict[str, Any]) -> tuple:
    return (result["pick_pix"], result["place_pix"], result["place_rot"])


def _compare(reference: list[dict], other: list[dict]) -> dict[str, Any]:
    """Share of identical actions, the near-ties among the others, and the largest heatmap difference
    relative to each map's peak."""
    same_pick = same_place = near = 0
    worst = 0.0
    for ref, got in zip(reference, other, strict=True):
        same_pick += ref["pick_pix"] == got["pick_pix"]
        same_place += (ref["place_pix"], ref["place_rot"]) == (got["place_pix"], got["place_rot"])
        if ref["pick_pix"] != got["pick_pix"]:
            near += ref["pick_heatmap"][got["pick_pix"]] >= (1 - NEAR_TIE) * ref["pick_heatmap"].max()
        for key in ("pick_heatmap", "place_heatmap"):
            worst = max(worst, float(np.abs(ref[key] - got[key]).max() / ref[key].max()))
    n = len(reference)
    return {
        "n": n,
        "same_pick": same_pick / n,
        "same_place": same_place / n,
        "pick_changes_that_are_near_ties": int(near),
        "max_heatmap_difference_over_peak": worst,
    }


def _act(agent: PickPlaceAgent, items: list[tuple[dict, str | None]], batch: int) -> list[dict]:
    out: list[dict] = []
    for i in range(0, len(items), batch):
        chunk = items[i : i + batch]
        out += agent.act_batch([o for o, _ in chunk], [lang for _, lang in chunk])
    return out


def batch_size_agreement(agent: PickPlaceAgent, items: list, sizes: list[int]) -> dict[str, Any]:
    """Actions of each observation alone against inside batches of k."""
    alone = _act(agent, items, 1)
    return {f"batch_{k}_vs_1": _compare(alone, _act(agent, items, k)) for k in sizes}


def setting_agreement(agent: PickPlaceAgent, items: list, **off: bool) -> dict[str, Any]:
    """Batch-1 actions with the default settings against with ``off`` switched off."""
    on = _act(agent, items, 1)
    agent.optimize_for_device(**off)
    result = _compare(on, _act(agent, items, 1))
    agent.optimize_for_device()
    return result


def graph_memory(make, items: list, worker_counts: list[int], device: torch.device) -> dict[str, Any]:
    """Per worker count N: a fresh agent acts with batch sizes 1..N (what an engine with N workers hands it)."""
    out = {}
    for n in worker_counts:
        gc.collect()
        torch.cuda.empty_cache()
        base_allocated, base_reserved = torch.cuda.memory_allocated(device), torch.cuda.memory_reserved(device)
        torch.cuda.reset_peak_memory_stats(device)
        agent = make()
        weights = torch.cuda.memory_allocated(device) - base_allocated
        for b in range(1, n + 1):
            batch = [items[i % len(items)] for i in range(b)]
            agent.act_batch([o for o, _ in batch], [lang for _, lang in batch])
        torch.cuda.synchronize(device)
        row = {
            "agent_weights_gib": weights / 2**30,
            "held_after_acting_gib": (torch.cuda.memory_allocated(device) - base_allocated - weights) / 2**30,
            "reserved_gib": (torch.cuda.memory_reserved(device) - base_reserved) / 2**30,
            "peak_allocated_gib": (torch.cuda.max_memory_allocated(device) - base_allocated) / 2**30,
            "graph_batch_sizes": agent._pick_graphs.captured_batch_sizes(),
        }
        gc.disable()
        del agent
        torch.cuda.empty_cache()
        row["left_after_drop_without_gc_mib"] = (torch.cuda.memory_allocated(device) - base_allocated) / 2**20
        gc.enable()
        out[f"workers_{n}"] = row
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--agent", choices=agent_names(), default="two_stream")
    parser.add_argument("--width", type=float, help="random agent's width (default: 1 on CUDA, 0.125 elsewhere)")
    parser.add_argument("--checkpoint", help="a checkpoint file to act with (default: random weights)")
    parser.add_argument("--tasks", nargs="+", default=DEFAULT_TASKS)
    parser.add_argument("--seeds", type=int, default=4, help="val episodes per task")
    parser.add_argument("--camera-scale", type=float, default=0.5)
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8], help="batch sizes compared with 1")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4, 8, 16], help="for graph_memory")
    args = parser.parse_args()
    device = torch.device(args.device)
    width = args.width or (1.0 if device.type == "cuda" else 0.125)
    if args.seeds < 1 or width <= 0 or min(args.sizes) < 1 or min(args.workers) < 1:
        parser.error("--seeds, --sizes and --workers must be >= 1 and --width > 0")

    def make() -> PickPlaceAgent:
        if args.checkpoint:
            return PickPlaceAgent.from_pretrained(args.checkpoint, device=device)
        torch.manual_seed(0)
        random_parts = dict.fromkeys(agent_class(args.agent).weight_sources, "random")
        return make_agent(args.agent, {"width": width, **random_parts}).to(device)

    items = observations(args.tasks, args.seeds, args.camera_scale)
    agent = make()
    report: dict[str, Any] = {
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        "agent": agent.name,
        "weights": args.checkpoint or f"random (width {width})",
        "observations": len(items),
        "tasks": args.tasks,
        "active_device_options": agent.active_device_options(),
        "batch_size_agreement": batch_size_agreement(agent, items, args.sizes),
    }
    if device.type == "cuda":
        report["graphs_vs_eager"] = setting_agreement(agent, items, act_graphs=False)
        if agent.encoder is not None and agent.active_device_options()["bf16_clip"]:
            report["fp32_vs_bf16"] = setting_agreement(agent, items, bf16_clip=False)
        del agent
        report["graph_memory"] = graph_memory(make, items, args.workers, device)
    report["environment"] = measurement_environment()
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
