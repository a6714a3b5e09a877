"""The trainer's loader alone: targets collated in the workers as the agent computes them, and batches ready
before a consumer asks for them."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch
from torch.utils.data import Dataset, default_collate

from cliport.agents import make_agent
from cliport.data.dataset import DemoDataset
from cliport.train.loader import ContrastPairSampler, TrainingCollate, training_loader


def test_the_collated_targets_are_the_agents(tmp_path, make_synthetic_dataset, tiny_config) -> None:
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    dataset = DemoDataset(str(tmp_path), "place-red-in-green", n_demos=2, seed=0)
    agent = make_agent("transporter_only", tiny_config("transporter_only", n_rotations=36))
    samples = [dataset[i] for i in range(len(dataset))]
    batch = TrainingCollate(36)(samples)
    assert "pose0" not in batch and "pose1" not in batch
    poses0 = np.stack([s["pose0"] for s in samples])
    poses1 = np.stack([s["pose1"] for s in samples])
    expected = agent.action_targets(poses0, poses1, (320, 160))
    for key, value in zip(("pick_pix", "place_pix", "place_rot"), expected, strict=True):
        assert batch[key].dtype == torch.int64 and torch.equal(batch[key], value), key
    assert batch["lang"] == [s["lang"] for s in samples] and batch["task"] == [s["task"] for s in samples]
    plain = default_collate(samples)  # torch's own collation of the images: the same tensors
    for key in ("color", "height"):
        assert batch[key].dtype == plain[key].dtype and torch.equal(batch[key], plain[key]), key


class _Stamped(Dataset):
    """A dataset whose samples record when their worker finished them (CLOCK_MONOTONIC is one clock for every
    process of the machine)."""

    def __init__(self, dataset: Dataset) -> None:
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)  # type: ignore[arg-type]

    def __getitem__(self, i: int) -> dict:
        sample = self.dataset[i]
        sample["done_at"] = time.monotonic()
        return sample


#: The consumer's time per batch-1 step. Generous on purpose: the default test run shares two cores with other
#: jobs, where a worker's sample takes 2.3 ms alone and several times that under load; the loader's rate itself
#: is measured by scripts/bench_train.py (loader_samples_per_s), not asserted here.
STEP_S = 0.025


@pytest.mark.parametrize("workers", [1, 2])
def test_batches_are_ready_before_the_training_step_asks(workers: int, tmp_path, make_synthetic_dataset) -> None:
    """A consumer that asks for a batch-1 batch every STEP_S seconds (a training step) finds almost every one
    finished before it asked: the workers keep the queue filled ahead of it. Without prefetching workers
    (``num_workers=0``) no batch is ready before it is asked for, which the test also checks."""
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    dataset = _Stamped(DemoDataset(str(tmp_path), "place-red-in-green", n_demos=2, seed=0))
    ready = {}
    for n_workers in (0, workers):
        loader = training_loader(dataset, 1, n_rotations=4, num_workers=n_workers, seed=0, pin_memory=False)
        batches = iter(loader)
        next(batches)  # the workers' start-up and their first episode reads
        outcomes = []
        for _ in range(40):
            time.sleep(STEP_S)
            asked = time.monotonic()
            batch = next(batches)
            outcomes.append(float(batch["done_at"][0]) < asked)
            assert batch["pick_pix"].shape == (1, 2) and batch["place_rot"].dtype == torch.int64
        ready[n_workers] = sum(outcomes) / len(outcomes)
        del batches, loader
    assert ready[0] == 0.0
    assert ready[workers] >= 0.9, ready


def test_contrast_pairs_come_one_after_the_other_with_one_seed() -> None:
    partners = [[1, 2], [0], []]
    items = list(ContrastPairSampler(partners, torch.Generator().manual_seed(3), num_samples=60))
    assert len(items) == 60
    assert items == list(ContrastPairSampler(partners, torch.Generator().manual_seed(3), num_samples=60))
    k, firsts = 0, []
    while k < len(items):
        (i, seed), k = items[k], k + 1
        firsts.append(i)
        if partners[i] and k < len(items):
            partner, partner_seed = items[k]
            assert partner in partners[i] and partner_seed == seed
            k += 1
    assert set(firsts) == {0, 1, 2}, "every sample is drawn"
    assert len({seed for _, seed in items}) > 20, "each pair its own seed"


def test_the_loader_pairs_contrasting_instructions_at_batch_1(tmp_path, make_two_bowl_dataset) -> None:
    make_two_bowl_dataset(str(tmp_path))
    dataset = DemoDataset(str(tmp_path), "put-one-block-in-bowl-seen-colors", every_instruction=True)
    batches = iter(training_loader(dataset, 1, 1, num_workers=0, seed=0, pin_memory=False, pair_contrasts=True))
    for _ in range(4):
        first, second = next(batches), next(batches)
        assert torch.equal(first["color"], second["color"])
        one, two = (batch["lang"][0].split() for batch in (first, second))  # put the X block in the Y bowl
        assert one[2] != two[2] and one[6] != two[6], "another block colour and another bowl colour"
        assert not torch.equal(first["pick_pix"], second["pick_pix"])
        assert not torch.equal(first["place_pix"], second["place_pix"])
