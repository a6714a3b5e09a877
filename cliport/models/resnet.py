"""Hourglass fully-convolutional ResNets: ResNet43_8s (Transporter) and the lateral ResNet45_10s (CLIPort)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import HeadStage, ResidualStage, UpStage, resize, scaled


class ResNet43_8s(nn.Module):  # noqa: N801 - the name used by the Transporter Networks paper
    """3x3 stem (64), encoder stages 64, 128/2, 256/2, 512/2 (stride on each stage's 3x3 conv), decoder
    stages 256, 128, 64 each followed by x2 up-sampling, and a 16-wide head: (N, in, H, W) at 1/8 and back.

    Height and width of the input must be multiples of 8.
    """

    def __init__(self, in_ch: int, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        w = [scaled(c, width) for c in (64, 128, 256, 512, 256, 128, 64)]
        self.stem = nn.Conv2d(in_ch, w[0], 3, padding=1)
        self.encoder = nn.Sequential(
            ResidualStage(w[0], w[0]),
            ResidualStage(w[0], w[1], stride=2),
            ResidualStage(w[1], w[2], stride=2),
            ResidualStage(w[2], w[3], stride=2),
        )
        self.decoder = nn.Sequential(UpStage(w[3], w[4]), UpStage(w[4], w[5]), UpStage(w[5], w[6]))
        self.head = HeadStage(w[6], scaled(16, width), out_ch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in_ch, H, W) -> (N, out_ch, H, W)."""
        x = F.relu(self.stem(x))
        return self.head(self.decoder(self.encoder(x)))


class ResNet45_10s(nn.Module):  # noqa: N801 - the name used by the CLIPort code base
    """Encoder to 1/16 at 1024 channels; five decoder stages 512, 256, 128, 64, 32, each followed by x2
    up-sampling, so the 16-wide head runs at twice the input resolution and is resized back (bilinear).

    Besides its output it returns six lateral features for the semantic stream: the inputs of the five
    decoder stages and of the head, at strides 16, 8, 4, 2, 1, 1/2 with widths 1024, 512, 256, 128, 64,
    32 (times the width multiplier). Height and width must be multiples of 16.
    """

    def __init__(self, in_ch: int, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        enc = [scaled(c, width) for c in (64, 128, 256, 512, 1024)]
        dec = [scaled(c, width) for c in (512, 256, 128, 64, 32)]
        self.lateral_widths = (enc[-1], *dec)
        self.stem = nn.Conv2d(in_ch, enc[0], 3, padding=1)
        self.encoder = nn.Sequential(
            ResidualStage(enc[0], enc[0]),
            *(ResidualStage(i, o, stride=2) for i, o in zip(enc[:-1], enc[1:], strict=True)),
        )
        self.decoder = nn.ModuleList(UpStage(i, o) for i, o in zip(self.lateral_widths[:-1], dec, strict=True))
        self.head = HeadStage(dec[-1], scaled(16, width), out_ch)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """(N, in_ch, H, W) -> ((N, out_ch, H, W), six laterals at strides 16, 8, 4, 2, 1, 1/2)."""
        size = x.shape[-2:]
        x = self.encoder(F.relu(self.stem(x)))
        laterals = []
        for stage in self.decoder:
            laterals.append(x)
            x = stage(x)
        laterals.append(x)
        return resize(self.head(x), size), laterals
