"""Resuming a run from its ``checkpoints/last.pt`` (:func:`resume_from_last`), or starting it with nets that can
learn (:func:`start_live`), and loading optimiser state saved on another device, layout or optimiser
implementation (:func:`load_optimizer_state`).

A run's ``last.pt`` keeps Adam's moments with the strides, dtype and device they had when saved: NCHW
for a run started on a CPU, before the CUDA speed work or with channels_last off, channels_last for one
saved on CUDA. ``torch.optim.Optimizer.load_state_dict`` keeps those strides, and it also takes the
implementation flags (``fused``, ``foreach``) from the file instead of from the optimiser built for
this device. Fused CUDA Adam then rejects moments whose layout differs from their parameter's.
"""

from __future__ import annotations

import os
from typing import Any

import torch

from cliport.errors import TrainError
from cliport.train.live_start import ensure_live
from cliport.train.loader import TrainingCollate
from cliport.train.run import TrainRun

#: Param-group keys that choose an implementation for this device rather than describe the training.
IMPLEMENTATION_KEYS = ("fused", "foreach", "capturable", "differentiable")


def load_optimizer_state(optimizer: torch.optim.Optimizer, state: dict[str, Any]) -> None:
    """Load a saved ``optimizer.state_dict()`` so that it works with this optimiser's parameters as they are.

    Hyper-parameters (learning rate, betas, ...) come from ``state``; the implementation flags
    (:data:`IMPLEMENTATION_KEYS`) stay this optimiser's. Every state tensor shaped like its parameter (Adam's
    ``exp_avg``, ``exp_avg_sq``) is copied into the parameter's dtype, device and strides (channels_last or
    not); ``step`` goes where the implementation wants it (float32 on the parameter's device for fused or
    capturable Adam, on the CPU otherwise). Nothing is shared with ``state``: it can be loaded again.
    """
    own = [{k: group[k] for k in IMPLEMENTATION_KEYS if k in group} for group in optimizer.param_groups]
    optimizer.load_state_dict(state)
    for group, implementation in zip(optimizer.param_groups, own, strict=True):
        group.update(implementation)
        on_device = bool(group.get("fused") or group.get("capturable"))
        for param in group["params"]:
            param_state = optimizer.state.get(param)
            if not param_state:
                continue
            for key, value in param_state.items():
                if not isinstance(value, torch.Tensor):
                    continue
                if key == "step":
                    device = param.device if on_device else torch.device("cpu")
                    param_state[key] = value.to(device=device, dtype=torch.float32, copy=True)
                elif value.shape == param.shape:
                    param_state[key] = torch.empty_like(param).copy_(value)


def resume_from_last(run: TrainRun) -> None:
    """Continue ``run`` from its ``checkpoints/last.pt``, if it has one: the agent's weights, the optimiser's state,
    the step, the seconds trained, the torch RNG and the nets drawn again at the start. TrainError for a checkpoint
    of another agent or recipe."""
    from cliport.agents import read_checkpoint

    last = run.folder.checkpoint("last")
    if not os.path.exists(last):
        return
    config = run.config
    payload = read_checkpoint(last)
    if payload["agent"] != config.agent:
        raise TrainError(f"{last} is a checkpoint of agent {payload['agent']!r}, not {config.agent!r}")
    saved_recipe = payload.get("recipe", "legacy")
    if saved_recipe != config.recipe:
        raise TrainError(f"{last} was trained with the {saved_recipe} recipe, not {config.recipe}")
    run.agent.load_trainable_state_dict(payload["state_dict"])
    load_optimizer_state(run.optimizer, payload["trainer"]["optimizer"])  # into this device's layout and Adam
    run.step = int(payload["trainer"]["step"])
    run.trained_before = float(payload["trainer"].get("trained_s", 0.0))
    torch.set_rng_state(payload["trainer"]["torch_rng"])
    run.init_draws = payload.get("init_draws", {})


def start_live(run: TrainRun) -> None:
    """Before a run's first step: draw again any net that could not learn from its first initial weights, on the
    first training sample (:func:`~cliport.train.live_start.ensure_live`); ``run.init_draws`` records them."""
    if run.step != 0:
        return
    agent = run.agent
    agent.train()
    first = TrainingCollate(agent.config.n_rotations)([run.dataset.sample(0, augment=False)])
    seed = run.config.seed * 1000 + run.rank
    run.init_draws = ensure_live(agent, agent.training_inputs(first, run.device), seed=seed)
    for name, record in run.init_draws.items():
        run.note(
            f"the {name} net's first initial weights could not learn ({record['reason']}); it starts from draw "
            f"{record['draws']} (cliport/train/live_start.py)"
        )
