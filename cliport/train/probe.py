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


def step_seconds(config: TrainConfig, steps: int = 4, warmup: int = 2) -> float:
    """Seconds per optimiser step of ``config``'s agent, recipe, batch size and device, as the trainer steps it
    (eager, as on a CPU; the loader and logging left out), averaged over ``steps`` after ``warmup`` steps.
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
        h, w = heightmap_shape()
        b = config.batch_size
        generator = np.random.default_rng(0)
        batch = {
            "color": torch.from_numpy(generator.integers(0, 256, (b, h, w, 3), dtype=np.uint8)),
            "height": torch.from_numpy(generator.uniform(0, 0.1, (b, h, w)).astype(np.float32)),
            "pick_pix": torch.tensor([[h // 3, w // 3]] * b),
            "place_pix": torch.tensor([[2 * h // 3, 2 * w // 3]] * b),
            "place_rot": torch.zeros(b, dtype=torch.long),
            "lang": [PROBE_INSTRUCTIONS[i % 2] for i in range(b)],
        }
        for _ in range(warmup):
            train_step(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        for _ in range(steps):
            train_step(batch)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return (time.perf_counter() - start) / steps
    finally:
        torch.set_rng_state(rng)
