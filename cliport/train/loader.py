"""The trainer's data path: demonstration samples drawn with replacement, augmented and collated in worker
processes, with the training targets computed there too, then pinned, so that the training step only copies
them to the device asynchronously.

Measured on the 2-core development machine (shared with other jobs, 2026-11-27): a place-red-in-green sample
costs ~2.3 ms in a worker (the SE(2) warp ~0.7 ms of it; an episode file is decompressed once per worker, ~2.5 ms,
then cached), and the loader alone served 175 samples/s at batch 1 with one worker and 230 with two
(``scripts/bench_train.py`` reports ``loader_samples_per_s``). Collating in the main process instead costs ~16 ms
a batch there: ``torch.stack`` with two threads on busy cores.
"""

from __future__ import annotations

from typing import Any

import torch
from torch.utils.data import DataLoader, Dataset, RandomSampler, default_collate

from cliport.agents.decode import action_targets


class TrainingCollate:
    """Collate samples into a batch and replace their poses ``pose0``/``pose1`` (B, 7) by the training targets
    (``pick_pix``, ``place_pix`` (B, 2) and ``place_rot`` (B,) int64, as
    :meth:`~cliport.agents.base.PickPlaceAgent.action_targets` computes them for ``n_rotations`` place bins), in the
    loader's workers. Picklable (workers may be spawned)."""

    def __init__(self, n_rotations: int) -> None:
        self.n_rotations = n_rotations

    def __call__(self, samples: list[dict[str, Any]]) -> dict[str, Any]:
        batch = default_collate(samples)
        hw = tuple(batch["height"].shape[-2:])
        pick, place, rotation = action_targets(batch.pop("pose0"), batch.pop("pose1"), hw, self.n_rotations)
        batch.update(pick_pix=pick, place_pix=place, place_rot=rotation)
        return batch


def training_loader(
    dataset: Dataset,
    batch_size: int,
    n_rotations: int,
    num_workers: int,
    seed: int,
    pin_memory: bool,
    prefetch_factor: int = 4,
) -> DataLoader:
    """An endless loader of augmented training batches of ``dataset``: samples drawn with replacement by a
    generator seeded with ``seed``, ``num_workers`` processes (persistent, each keeping ``prefetch_factor``
    batches ready), the targets collated in them (:class:`TrainingCollate`) and, with ``pin_memory``, every
    tensor pinned for asynchronous copies to a GPU."""
    generator = torch.Generator().manual_seed(seed)
    sampler = RandomSampler(dataset, replacement=True, num_samples=10**9, generator=generator)
    return DataLoader(
        dataset,
        batch_size=batch_size,
        sampler=sampler,
        num_workers=num_workers,
        persistent_workers=num_workers > 0,
        prefetch_factor=prefetch_factor if num_workers > 0 else None,
        pin_memory=pin_memory,
        drop_last=True,
        collate_fn=TrainingCollate(n_rotations),
    )
