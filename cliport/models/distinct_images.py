"""Image-only work done once per distinct image of a batch.

A contrasting pair (``pair_contrasts``) shows a net one image under two instructions, and a held-out check shows
it one scene under its six. In the nets over a frozen encoder, the spatial stream, the encoder's trunk, the
semantic decoder's bottleneck and the skip's share of each up-block's first convolution read the image alone;
only what follows a language gate depends on the sentence. :func:`distinct_images` finds the repeated images of
a batch, those parts run once per distinct image, and :func:`per_sample` gathers their outputs back to one per
sample (autograd then sums the repeats' gradients). The values are those of the per-sample computation up to
float rounding (a convolution over a batch of one rounds as over a batch of two; the gradients are summed in
another order).

Only on the CPU: comparing images reads the values on the host, which a captured CUDA graph must never do.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

#: Device types on which a batch's repeated images are looked for.
DISTINCT_DEVICES = {"cpu"}


@dataclass(frozen=True)
class DistinctImages:
    """A batch's distinct images (D, C, H, W), in order of first appearance, and each sample's among them (N,)."""

    images: torch.Tensor
    index: torch.Tensor


def distinct_images(x: torch.Tensor) -> DistinctImages | None:
    """(N, C, H, W) -> its D < N distinct images and the (N,) int64 index of each sample's, or None where every
    image differs (or N is 1, or the batch is on a device not in :data:`DISTINCT_DEVICES`)."""
    n = x.shape[0]
    if n < 2 or x.device.type not in DISTINCT_DEVICES:
        return None
    firsts: list[int] = []
    index: list[int] = []
    for i in range(n):
        same = next((k for k, first in enumerate(firsts) if torch.equal(x[i], x[first])), None)
        if same is None:
            same = len(firsts)
            firsts.append(i)
        index.append(same)
    if len(firsts) == n:
        return None
    return DistinctImages(x[firsts], torch.tensor(index, device=x.device))


def per_sample(x: torch.Tensor, index: torch.Tensor | None) -> torch.Tensor:
    """(D, ...) per distinct image -> (N, ...) per sample along ``index`` (N,); ``x`` itself where index is None."""
    return x if index is None else x.index_select(0, index)
