"""The fusions the reference's CLIPort nets use, named after their classes in its core/fusion.py.

Two feature maps: :class:`LateralFusion` (``FusionConvLat``: the semantic decoder's lateral inputs from the
spatial stream), :class:`AddFusion` (``FusionAdd``) and :class:`ConvFusion` (``FusionConv``), which join the two
streams' outputs. A map and the sentence: :func:`language_gate` (``FusionMult``, the LingUNet decoders' gates).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class LateralFusion(nn.Module):
    """concat(semantic, spatial lateral) -> ReLU -> 1x1 conv (no bias) to ``out_ch`` channels: the reference's
    ``FusionConvLat``."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_ch, out_ch, 1, bias=False)

    def forward(self, x: torch.Tensor, lateral: torch.Tensor) -> torch.Tensor:
        """(N, c, H, W), (N, in_ch - c, H, W) -> (N, out_ch, H, W)."""
        return self.conv(F.relu(torch.cat([x, lateral], dim=1)))


class AddFusion(nn.Module):
    """The two streams' outputs summed: the reference's ``FusionAdd`` (fusion type "add", its pick nets)."""

    def forward(self, spatial: torch.Tensor, semantic: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W), (N, C, H, W) -> (N, C, H, W)."""
        return spatial + semantic


class ConvFusion(nn.Conv2d):
    """concat(spatial, semantic) -> ReLU -> 1x1 conv (no bias) from ``2 * ch`` to ``ch`` channels: the reference's
    ``FusionConv`` (fusion type "conv", its key and query nets). A ``Conv2d`` itself, so its weight is ``weight``."""

    def __init__(self, ch: int) -> None:
        super().__init__(2 * ch, ch, 1, bias=False)

    def forward(  # type: ignore[override]  # two maps, where Conv2d.forward takes one
        self, spatial: torch.Tensor, semantic: torch.Tensor
    ) -> torch.Tensor:
        """(N, ch, H, W), (N, ch, H, W) -> (N, ch, H, W)."""
        return super().forward(F.relu(torch.cat([spatial, semantic], dim=1)))


def language_gate(x: torch.Tensor, projected_sentence: torch.Tensor) -> torch.Tensor:
    """(N, C, H, W) map times a (N, C) projection of the sentence, per channel: the reference's ``FusionMult``."""
    return x * projected_sentence[:, :, None, None]
