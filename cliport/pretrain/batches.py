"""What one pretraining step sees: a batch of crops, a caption for each and which captions are true of which crops.

A crop's caption is drawn when its batch is made (a random template; the colour sometimes left out; a relation
crop's relation), so that every epoch reads new sentences about the same pixels. A batch is a pure function of
the run's seed and the step (:meth:`CaptionedCrops.batch`), so a resumed run sees the batches it would have seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from cliport.pretrain.cache import CropSet
from cliport.pretrain.vocabulary import Thing, crop_facts, relation_caption, thing_caption


@dataclass
class Batch:
    """``images`` (B, 3, S, S) float in [0, 1]; ``captions`` (B,) strings, caption i written for image i;
    ``positives`` (B, B) bool, [i, j] when caption j is true of image i."""

    images: torch.Tensor
    captions: list[str]
    positives: torch.Tensor


def resize_images(images: np.ndarray, size: int) -> torch.Tensor:
    """(N, S, S, 3) uint8 -> (N, 3, size, size) uint8, area-averaged (or bilinear when growing)."""
    x = torch.from_numpy(images).permute(0, 3, 1, 2)
    if x.shape[-1] == size:
        return x.contiguous()
    mode = "area" if x.shape[-1] > size else "bilinear"
    out = []
    for chunk in x.split(1024):
        kwargs = {} if mode == "area" else {"align_corners": False}
        out.append(F.interpolate(chunk.float(), size=(size, size), mode=mode, **kwargs).round().clamp(0, 255))
    return torch.cat(out).to(torch.uint8)


def caption_for(meta: dict, rng: np.random.Generator) -> tuple[str, str]:
    """A caption of a crop (its relation where it has one, else its first thing) and the caption's key."""
    things = [Thing.from_list(t) for t in meta["things"]]
    if meta.get("relation") is not None:
        i, relation, j = meta["relation"]
        return relation_caption(things[i], relation, things[j], rng)
    return thing_caption(things[0], rng)


def facts_of(meta: dict) -> set[str]:
    """The keys of every caption true of a crop."""
    things = [Thing.from_list(t) for t in meta["things"]]
    positions = [(float(x), float(y)) for x, y in meta["positions"]] if meta.get("positions") is not None else None
    return crop_facts(things, positions)


class CaptionedCrops:
    """A split's crops at the model's image size, with what is true of each, drawn into batches."""

    def __init__(self, crops: CropSet, image_size: int) -> None:
        self.images = resize_images(crops.images, image_size)
        self.meta = crops.meta
        self.facts = [facts_of(m) for m in crops.meta]

    def __len__(self) -> int:
        return len(self.meta)

    def batch(self, indices: np.ndarray, rng: np.random.Generator) -> Batch:
        """The crops ``indices`` with a fresh caption each (drawn from ``rng``)."""
        drawn = [caption_for(self.meta[int(i)], rng) for i in indices]
        captions = [text for text, _ in drawn]
        keys = [key for _, key in drawn]
        positives = torch.tensor([[key in self.facts[int(i)] for key in keys] for i in indices], dtype=torch.bool)
        images = self.images[torch.as_tensor(indices, dtype=torch.long)].float() / 255
        return Batch(images, captions, positives)

    def step_batch(self, seed: int, step: int, batch_size: int) -> Batch:
        """Step ``step``'s batch of a run seeded ``seed``: ``batch_size`` distinct crops and their captions."""
        rng = np.random.default_rng([seed, step])
        indices = rng.choice(len(self), size=min(batch_size, len(self)), replace=False)
        return self.batch(indices, rng)
