"""The trainer's data path: demonstration samples drawn with replacement, augmented and collated in worker
processes, with the training targets computed there too, then pinned, so that the training step only copies
them to the device asynchronously.

Measured on the 2-core development machine (shared with other jobs, 2026-11-27): a place-red-in-green sample
costs ~2.1-2.3 ms in a worker (the SE(2) warp ~0.7 ms of it; an episode file is decompressed once per worker,
~2.5 ms, then cached), and the loader alone served 175-314 samples/s at batch 1 with one worker and 158-295 with
two (from a load of 10 to a nearly idle machine; ``scripts/bench_train.py`` reports the loader's rate). Collating
a batch-1 sample with torch's default collate in the main process (no workers) cost ~16 ms there (``torch.stack``
on two threads); :class:`TrainingCollate` stacks with numpy (0.04 ms).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, RandomSampler, Sampler, default_collate

from cliport.agents.decode import action_targets


class TrainingCollate:
    """Collate samples into a batch and replace their poses ``pose0``/``pose1`` (B, 7) by the training targets
    (``pick_pix``, ``place_pix`` (B, 2) and ``place_rot`` (B,) int64, as
    :meth:`~cliport.agents.base.PickPlaceAgent.action_targets` computes them for ``n_rotations`` place bins), in the
    loader's workers. Picklable (workers may be spawned)."""

    def __init__(self, n_rotations: int) -> None:
        self.n_rotations = n_rotations

    def __call__(self, samples: list[dict[str, Any]]) -> dict[str, Any]:
        batch: dict[str, Any] = {}
        for key in samples[0]:
            values = [sample[key] for sample in samples]
            if isinstance(values[0], np.ndarray):
                # numpy's stack, not torch's: torch.stack of a few small arrays took ~16 ms with two threads on
                # the 2-core machine (0.04 ms so), when the loader collates in the main process (no workers).
                batch[key] = torch.from_numpy(np.stack(values))
            elif isinstance(values[0], str):
                batch[key] = values
            else:
                batch[key] = default_collate(values)
        hw = tuple(batch["height"].shape[-2:])
        pick, place, rotation = action_targets(batch.pop("pose0"), batch.pop("pose1"), hw, self.n_rotations)
        batch.update(pick_pix=pick, place_pix=place, place_rot=rotation)
        return batch


class ContrastPairSampler(Sampler[tuple[int, int]]):
    """Samples drawn with replacement, each followed at once by a contrasting one: its scene under an
    instruction that names another pick and another place
    (:meth:`~cliport.data.dataset.DemoDataset.contrasting`), the two with one augmentation seed: items
    ``(index, seed)``. A sample without a contrast comes alone.

    At batch 1 the pair is two consecutive steps on the same augmented image whose targets differ only by the
    words: what a net can learn from the image alone (a block, a bowl) pulls one way and then the other, and
    what it must read from the sentence pulls the same way twice."""

    def __init__(self, partners: list[list[int]], generator: torch.Generator, num_samples: int = 10**9) -> None:
        self.partners, self.generator, self.num_samples = partners, generator, num_samples

    def __len__(self) -> int:
        return self.num_samples

    def __iter__(self) -> Iterator[tuple[int, int]]:
        n, yielded = len(self.partners), 0
        while yielded < self.num_samples:
            i, seed = (int(v) for v in torch.randint(2**62, (2,), generator=self.generator))
            i %= n
            yield i, seed
            yielded += 1
            if self.partners[i] and yielded < self.num_samples:
                pick = int(torch.randint(len(self.partners[i]), (1,), generator=self.generator))
                yield self.partners[i][pick], seed
                yielded += 1


def training_loader(
    dataset: Dataset,
    batch_size: int,
    n_rotations: int,
    num_workers: int,
    seed: int,
    pin_memory: bool,
    prefetch_factor: int = 4,
    pair_contrasts: bool = False,
) -> DataLoader:
    """An endless loader of augmented training batches of ``dataset``: samples drawn with replacement by a
    generator seeded with ``seed`` (``pair_contrasts``: each followed by a contrasting one,
    :class:`ContrastPairSampler`; the dataset must have ``contrasting``), ``num_workers`` processes
    (persistent, each keeping ``prefetch_factor`` batches ready), the targets collated in them
    (:class:`TrainingCollate`) and, with ``pin_memory``, every tensor pinned for asynchronous copies to a GPU."""
    generator = torch.Generator().manual_seed(seed)
    sampler: Sampler
    if pair_contrasts:
        sampler = ContrastPairSampler(dataset.contrasting(), generator)  # type: ignore[attr-defined]  # a DemoDataset
    else:
        sampler = RandomSampler(dataset, replacement=True, num_samples=10**9, generator=generator)  # type: ignore[arg-type]  # a map-style dataset: it has __len__, which torch's Dataset type does not declare
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
