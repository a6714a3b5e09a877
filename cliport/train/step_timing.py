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
from cliport.train.step_loop import autocast_dtype
from cliport.utils.device import resolve_device

#: Two instructions, so that an agent centring its sentence features has a mean to centre on.
PROBE_INSTRUCTIONS = ("put the red block in the green bowl", "put the blue block in the brown bowl")


def probe_batches(n: int, batch_size: int, pair_contrasts: bool = False) -> list[dict[str, torch.Tensor | list[str]]]:
    """``n`` synthetic training batches of ``batch_size`` samples on images of their own, as training sees them:
    the frozen trunk keeps recent images' features, so an image seen before costs less. ``pair_contrasts``:
    the samples come in pairs, each image twice under the two instructions in turn, as the contrasting pairs do,
    picking and placing at other pixels (the other instruction names another block and bowl); at batch 1 the pair
    is two steps, at batch 2 one batch."""
    h, w = heightmap_shape()
    generator = np.random.default_rng(0)
    per_image = 2 if pair_contrasts else 1
    images = [
        (
            torch.from_numpy(generator.integers(0, 256, (h, w, 3), dtype=np.uint8)),
            torch.from_numpy(generator.uniform(0, 0.1, (h, w)).astype(np.float32)),
        )
        for _ in range(-(-n * batch_size // per_image))
    ]
    batches: list[dict[str, torch.Tensor | list[str]]] = []
    for i in range(n):
        samples = range(i * batch_size, (i + 1) * batch_size)
        batches.append({
            "color": torch.stack([images[k // per_image][0] for k in samples]),
            "height": torch.stack([images[k // per_image][1] for k in samples]),
            "pick_pix": torch.tensor([[h // 3, w // (3 + k % 2)] for k in samples]),
            "place_pix": torch.tensor([[2 * h // 3, 2 * w // (3 + k % 2)] for k in samples]),
            "place_rot": torch.zeros(batch_size, dtype=torch.long),
            "lang": [PROBE_INSTRUCTIONS[k % 2] for k in samples],
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
        if agent.phrase_bank is not None:
            agent.phrase_bank.fit(agent.encoder, list(PROBE_INSTRUCTIONS))
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
