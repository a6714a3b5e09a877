"""cliport-train --compile on the CPU: 50 steps of the quickstart's task (place-red-in-green, transporter_only, the
ravens recipe, tiny width, two synthetic demos) give the eager run's losses and weights within float32 noise.

The noise is measured in the test: the same eager run with oneDNN's convolutions switched off (PyTorch's own
kernels: the same arithmetic, summed in another order) differs from the eager run by rounding alone, and that
difference grows over the steps as the compiled run's does: Adam turns the rounding of a near-zero gradient into a
step of up to lr, so the largest single weight difference says little (noise moved one weight by 6e-4 when no
weight moved more than 5.6e-3). Weights are therefore compared by how far they are from the eager run relative to
how far the eager run moved them from their initial values (the whole net, and its worst tensor); losses by their
largest difference over the 50 steps, which metrics.csv rounds to 5 decimals.

Measured on the 2-core machine (shared, 2026-11-27): oneDNN off against eager 2e-5 (losses), 0.43 % (weights),
2.1 % (worst tensor); compiled against eager 8e-5, 1.04 %, 6.6 %. The compiled run (Inductor's generated C++,
fused and reordered more) must stay within NOISE_FACTOR = 10 times the measured noise, the losses' noise taken
as at least two roundings of metrics.csv: a compiled step that lost an input or an update differs by orders
more (a tensor left untrained is 100 % off). e2e: the three runs and the compilation take ~15 minutes there.
"""

from __future__ import annotations

import contextlib
import os

import pytest
import torch

from cliport.agents import make_agent
from cliport.train.config import TrainConfig
from cliport.train.trainer import train
from cliport.utils.files import load_torch
from cliport.utils.run_dir import RunDir

STEPS = 50
NOISE_FACTOR = 10.0
#: metrics.csv rounds the losses to 5 decimals.
CSV_ROUNDING = 1e-5


def _run(tmp_path, name: str, compile: bool = False, onednn: bool = True) -> tuple[torch.Tensor, dict]:
    config = TrainConfig.build(
        {
            "agent": "transporter_only", "task": "place-red-in-green", "recipe": "ravens", "n_demos": 2,
            "n_steps": STEPS, "batch_size": 1, "data_dir": str(tmp_path), "run_dir": str(tmp_path / name),
            "device": "cpu", "num_workers": 0, "val_episodes": 0, "checkpoint_steps": [STEPS],
            "checkpoint_every": 0, "log_every": 1, "compile": compile,
            "agent_config": {"width": 0.125, "crop_size": 32, "n_rotations": 1},
        }
    )  # fmt: skip
    with contextlib.nullcontext() if onednn else torch.backends.mkldnn.flags(enabled=False):
        train(config, progress=False)
    with open(os.path.join(tmp_path, name, "metrics.csv")) as f:
        rows = [[float(v) for v in line.split(",")[1:4]] for line in f.read().split()[1:]]
    weights = load_torch(RunDir(str(tmp_path / name)).checkpoint(STEPS))["state_dict"]
    return torch.tensor(rows, dtype=torch.float64), {k: v.double() for k, v in weights.items()}


def _initial_weights() -> dict:
    """The weights every run starts from (train() seeds torch with the run's seed 0 before building the agent)."""
    torch.manual_seed(0)
    agent = make_agent("transporter_only", {"width": 0.125, "crop_size": 32, "n_rotations": 1})
    return {k: v.double() for k, v in agent.trainable_state_dict().items()}


def _difference(a: tuple, b: tuple, start: dict) -> tuple[float, float, float]:
    """(largest loss difference, |weights a - b| / |weights a - start| over the net, and over its worst tensor)."""
    (losses_a, weights_a), (losses_b, weights_b) = a, b
    apart = sum(float(((weights_a[k] - weights_b[k]) ** 2).sum()) for k in start) ** 0.5
    moved = sum(float(((weights_a[k] - start[k]) ** 2).sum()) for k in start) ** 0.5
    worst = max(
        float((weights_a[k] - weights_b[k]).norm() / (weights_a[k] - start[k]).norm())
        for k in start
        if float((weights_a[k] - start[k]).norm()) > 0
    )
    return float((losses_a - losses_b).abs().max()), apart / moved, worst


@pytest.mark.e2e
def test_a_compiled_run_trains_as_the_eager_one(tmp_path, make_synthetic_dataset, record_property) -> None:
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    eager = _run(tmp_path, "eager")
    assert eager[0].shape == (STEPS, 3) and torch.isfinite(eager[0]).all()
    assert eager[0][-10:, 0].mean() < eager[0][:10, 0].mean()  # it trained
    perturbed = _run(tmp_path, "no-onednn", onednn=False)
    compiled = _run(tmp_path, "compiled", compile=True)
    start = _initial_weights()
    assert set(start) == set(eager[1])
    noise = _difference(eager, perturbed, start)
    got = _difference(eager, compiled, start)
    print(f"compiled - eager: {got}; oneDNN off - eager: {noise} (losses, weights, worst tensor)")
    record_property("compiled_vs_eager", list(got))
    record_property("rounding_noise", list(noise))
    assert noise[1] > 0  # the perturbation did change the rounding
    assert got[0] <= NOISE_FACTOR * max(noise[0], 2 * CSV_ROUNDING)
    assert got[1] <= NOISE_FACTOR * noise[1] and got[2] <= NOISE_FACTOR * noise[2]
