"""How fast this machine trains a run's configuration, measured before any demonstration exists: a few real
optimiser steps of the configured agent on a synthetic batch of the run's shapes (the language lesson's first
line says what it found and what that means for its time budget)."""

from __future__ import annotations

import time

import numpy as np
import torch

from cliport.agents import make_agent
from cliport.env.heightmap import heightmap_shape
from cliport.train.config import TrainConfig
from cliport.train.graphed_step import TrainStep
from cliport.train.trainer import autocast_dtype
from cliport.utils.device import resolve_device

#: Two instructions, so that an agent centring its sentence features has a mean to centre on.
PROBE_INSTRUCTIONS = ("put the red block in the green bowl", "put the blue block in the brown bowl")


def probe_batches(n: int, batch_size: int, pair_contrasts: bool = False) -> list[dict[str, torch.Tensor | list[str]]]:
    """``n`` synthetic training batches of ``batch_size`` samples, each on images of its own, as training sees
    them: a step on an image seen the step before costs less (the frozen trunk keeps recent images' features).
    ``pair_contrasts``: every second batch repeats the one before it under the other instruction, as the
    contrasting pairs do."""
    h, w = heightmap_shape()
    generator = np.random.default_rng(0)
    batches: list[dict[str, torch.Tensor | list[str]]] = []
    color = height = torch.empty(0)
    for i in range(n):
        repeat = pair_contrasts and i % 2 == 1
        lang = PROBE_INSTRUCTIONS[::-1] if repeat else PROBE_INSTRUCTIONS
        if not repeat:
            color = torch.from_numpy(generator.integers(0, 256, (batch_size, h, w, 3), dtype=np.uint8))
            height = torch.from_numpy(generator.uniform(0, 0.1, (batch_size, h, w)).astype(np.float32))
        batches.append({
            "color": color,
            "height": height,
            "pick_pix": torch.tensor([[h // 3, w // 3]] * batch_size),
            "place_pix": torch.tensor([[2 * h // 3, 2 * w // 3]] * batch_size),
            "place_rot": torch.zeros(batch_size, dtype=torch.long),
            "lang": [lang[j % 2] for j in range(batch_size)],
        })  # fmt: skip
    return batches


def step_seconds(config: TrainConfig, steps: int = 4, warmup: int = 2) -> float:
    """Seconds per optimiser step of ``config``'s agent, recipe, batch size and device, as the trainer steps it
    (eager, as on a CPU; the loader and logging left out), averaged over ``steps`` after ``warmup`` steps, on the
    batches of :func:`probe_batches` (with ``config.pair_contrasts``' pairs).
    The caller's torch random state is left as it was."""
    if steps < 1 or warmup < 0:
        raise ValueError(f"the probe needs steps >= 1 and warmup >= 0, got {steps} and {warmup}")
    rng = torch.get_rng_state()
    try:
        torch.manual_seed(0)
        device = resolve_device(config.device)
        recipe = config.training_recipe()
        agent = make_agent(config.agent, config.agent_config).to(device)
        optimizer, _ = recipe.prepare(agent)
        if agent.centers_sentences:
            agent.fit_sentence_centering(list(PROBE_INSTRUCTIONS))
        train_step = TrainStep(
            agent,
            optimizer,
            recipe.loss,
            autocast_dtype=autocast_dtype(config, device),
            graphs=False,
            parallel_heads=config.parallel_heads,
        )
        batches = probe_batches(warmup + steps, config.batch_size, config.pair_contrasts)
        for batch in batches[:warmup]:
            train_step(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        for batch in batches[warmup:]:
            train_step(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return (time.perf_counter() - start) / steps
    finally:
        torch.set_rng_state(rng)
