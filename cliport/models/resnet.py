"""Hourglass fully-convolutional ResNets: ResNet43_8s (Transporter) and the lateral ResNet45_10s (CLIPort).

Reproduces the reference's ``ResNet43_8s`` (cliport/models/resnet.py) and ``ResNet45_10s``
(cliport/models/resnet_lat.py) with ``batchnorm: False``, as the reference trains them.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import HeadStage, ResidualStage, UpStage, resize, scaled


class ResNet43_8s(nn.Sequential):  # noqa: N801 - the name used by the Transporter Networks paper
    """3x3 stem (64), encoder stages 64, 128/2, 256/2, 512/2 (stride on each stage's 3x3 conv), decoder
    stages 256, 128, 64 each followed by x2 up-sampling, and a 16-wide head: (N, in, H, W) at 1/8 and back.

    One ``Sequential``, as the reference's ``layers``; its sections are named children (``stem``,
    ``encoder``, ``decoder``, ``head``: the names of this net's state dict). Height and width of the input
    must be multiples of 8: (N, in_ch, H, W) -> (N, out_ch, H, W).
    """

    def __init__(self, in_ch: int, out_ch: int, width: float = 1.0) -> None:
        w64, w128, w256, w512 = (scaled(c, width) for c in (64, 128, 256, 512))
        super().__init__(
            OrderedDict(
                # the reference's conv1
                stem=nn.Conv2d(in_ch, w64, 3, padding=1),
                relu=nn.ReLU(),
                # its fcn
                encoder=nn.Sequential(
                    ResidualStage(w64, w64),
                    ResidualStage(w64, w128, stride=2),
                    ResidualStage(w128, w256, stride=2),
                    ResidualStage(w256, w512, stride=2),
                ),
                # its head
                decoder=nn.Sequential(UpStage(w512, w256), UpStage(w256, w128), UpStage(w128, w64)),
                # its conv2
                head=HeadStage(w64, scaled(16, width), out_ch),
            )
        )


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
