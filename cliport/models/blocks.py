"""Residual building blocks shared by the Transporter and CLIPort networks (no batch norm)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class BottleneckConvBlock(nn.Module):
    """1x1 -> 3x3 -> 1x1 bottleneck with a 1x1 projection shortcut; the stride sits on the first 1x1."""

    def __init__(self, in_ch: int, filters: tuple[int, int, int], stride: int = 1, final_relu: bool = True) -> None:
        super().__init__()
        f1, f2, f3 = filters
        self.conv1 = nn.Conv2d(in_ch, f1, 1, stride=stride)
        self.conv2 = nn.Conv2d(f1, f2, 3, padding=1)
        self.conv3 = nn.Conv2d(f2, f3, 1)
        self.shortcut = nn.Conv2d(in_ch, f3, 1, stride=stride)
        self.final_relu = final_relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in_ch, H, W) -> (N, f3, H / stride, W / stride)."""
        y = F.relu(self.conv1(x))
        y = F.relu(self.conv2(y))
        y = self.conv3(y) + self.shortcut(x)
        return F.relu(y) if self.final_relu else y


class BottleneckIdentityBlock(nn.Module):
    """1x1 -> 3x3 -> 1x1 bottleneck added to its own input (input width = output width)."""

    def __init__(self, ch: int, filters: tuple[int, int], final_relu: bool = True) -> None:
        super().__init__()
        f1, f2 = filters
        self.conv1 = nn.Conv2d(ch, f1, 1)
        self.conv2 = nn.Conv2d(f1, f2, 3, padding=1)
        self.conv3 = nn.Conv2d(f2, ch, 1)
        self.final_relu = final_relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, ch, H, W) -> (N, ch, H, W)."""
        y = F.relu(self.conv1(x))
        y = F.relu(self.conv2(y))
        y = self.conv3(y) + x
        return F.relu(y) if self.final_relu else y


class ResidualStage(nn.Sequential):
    """A bottleneck conv block followed by an identity block, both `width` wide."""

    def __init__(self, in_ch: int, width: int, stride: int = 1, final_relu: bool = True) -> None:
        super().__init__(
            BottleneckConvBlock(in_ch, (width, width, width), stride=stride, final_relu=final_relu),
            BottleneckIdentityBlock(width, (width, width), final_relu=final_relu),
        )


class HeadStage(nn.Sequential):
    """Output stage: conv block and identity block with 16-wide bottlenecks, no final ReLU."""

    def __init__(self, in_ch: int, hidden: int, out_ch: int) -> None:
        super().__init__(
            BottleneckConvBlock(in_ch, (hidden, hidden, out_ch), final_relu=False),
            BottleneckIdentityBlock(out_ch, (hidden, hidden), final_relu=False),
        )


class Upsample2x(nn.Module):
    """Bilinear x2 up-sampling."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) -> (N, C, 2H, 2W)."""
        return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)


def scaled(width: int, multiplier: float) -> int:
    """Channel count `width` scaled by `multiplier`, at least 4."""
    return max(4, int(round(width * multiplier)))
