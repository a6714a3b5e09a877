"""Hourglass fully-convolutional ResNets: ResNet43_8s (Transporter) and the lateral ResNet45_10s (CLIPort)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import HeadStage, ResidualStage, Upsample2x, scaled


class ResNet43_8s(nn.Module):  # noqa: N801 - the name used by the Transporter Networks paper
    """Encoder to 1/8 resolution (64, 128, 256, 512) and decoder back (256, 128, 64) with a 16-wide head.

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
        self.decoder = nn.Sequential(
            ResidualStage(w[3], w[4]),
            Upsample2x(),
            ResidualStage(w[4], w[5]),
            Upsample2x(),
            ResidualStage(w[5], w[6]),
            Upsample2x(),
        )
        self.head = HeadStage(w[6], scaled(16, width), out_ch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in_ch, H, W) -> (N, out_ch, H, W)."""
        x = F.relu(self.stem(x))
        return self.head(self.decoder(self.encoder(x)))


class ResNet45_10s(nn.Module):  # noqa: N801 - the name used by the CLIPort code base
    """Encoder to 1/16 resolution at 1024 channels; decoder 512-256-128-64-32 with bilinear x2 up-sampling.

    Besides its output it returns the five decoder activations (before each up-sampling) as lateral
    features for the semantic stream, at strides 16, 8, 4, 2, 1 with widths 512, 256, 128, 64, 32
    (times the width multiplier). Height and width must be multiples of 16.
    """

    decoder_widths = (512, 256, 128, 64, 32)

    def __init__(self, in_ch: int, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        enc = [scaled(c, width) for c in (64, 128, 256, 512, 1024)]
        dec = [scaled(c, width) for c in self.decoder_widths]
        self.lateral_widths = tuple(dec)
        self.stem = nn.Conv2d(in_ch, enc[0], 3, padding=1)
        self.encoder = nn.Sequential(
            ResidualStage(enc[0], enc[0]),
            ResidualStage(enc[0], enc[1], stride=2),
            ResidualStage(enc[1], enc[2], stride=2),
            ResidualStage(enc[2], enc[3], stride=2),
            ResidualStage(enc[3], enc[4], stride=2),
        )
        ins = [enc[4], *dec[:-1]]
        self.decoder = nn.ModuleList(ResidualStage(i, o) for i, o in zip(ins, dec, strict=True))
        self.upsample = Upsample2x()
        self.head = HeadStage(dec[-1], scaled(16, width), out_ch)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """(N, in_ch, H, W) -> ((N, out_ch, H, W), [laterals at strides 16, 8, 4, 2, 1])."""
        x = self.encoder(F.relu(self.stem(x)))
        laterals = []
        for i, stage in enumerate(self.decoder):
            x = stage(x)
            laterals.append(x)
            if i < len(self.decoder) - 1:
                x = self.upsample(x)
        return self.head(x), laterals
