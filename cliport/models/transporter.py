"""The Transporter Networks net: input normalisation + :class:`~cliport.models.resnet.ResNet43_8s`.

Reproduces the reference's ``ResNet43_8s`` (cliport/models/resnet.py) as its transporter agent's
attention and transport streams use it, with ``preprocess(x, dist='transporter')`` first.
"""

from __future__ import annotations

import torch
from torch import nn

from cliport.models.preprocess import IN_CHANNELS, transporter_normalize
from cliport.models.resnet import ResNet43_8s


class TransporterNet(nn.Module):
    """Transporter Networks' net: normalisation + ResNet43_8s. Ignores language."""

    def __init__(self, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        self.resnet = ResNet43_8s(IN_CHANNELS, out_ch, width)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 8), sentence ignored -> (N, out_ch, H, W)."""
        return self.resnet(transporter_normalize(x))
