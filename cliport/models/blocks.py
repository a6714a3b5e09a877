"""Residual building blocks shared by the Transporter and CLIPort networks (no batch norm), and bilinear x2
up-sampling."""

from __future__ import annotations

from collections.abc import Sequence

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


UPSAMPLE_MODES = ("auto", "stencil", "interpolate")
_upsample_mode = "auto"


def set_upsample_mode(mode: str) -> None:
    """How exact x2 bilinear up-sampling is computed, process-wide.

    ``"auto"`` (default): the elementwise stencil of :func:`upsample2x_stencil` on accelerators, where
    ``aten::upsample_bilinear2d`` dominated the profile (slow atomic-add backward, NCHW only), and
    ``F.interpolate`` on the CPU, whose native kernel is faster there. ``"stencil"`` and ``"interpolate"``
    force one of them everywhere. Both give the same function up to float rounding.
    """
    global _upsample_mode
    if mode not in UPSAMPLE_MODES:
        raise ValueError(f"upsample mode must be one of {UPSAMPLE_MODES}, got {mode!r}")
    _upsample_mode = mode


def upsample_mode() -> str:
    """The mode set by :func:`set_upsample_mode`."""
    return _upsample_mode


def _empty_like_layout(x: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    channels_last = x.is_contiguous(memory_format=torch.channels_last) and not x.is_contiguous()
    layout = torch.channels_last if channels_last else torch.contiguous_format
    return torch.empty(shape, dtype=x.dtype, device=x.device, memory_format=layout)


def _upsample2x_along(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Doubles dim 2 or 3 of (N, C, H, W): out[2i] = 0.75 x[i] + 0.25 x[i-1], out[2i+1] = 0.75 x[i] +
    0.25 x[i+1], indices clamped to the edges."""

    def at(index: slice | int) -> tuple[slice | int, ...]:
        return (slice(None),) * dim + (index,)

    shape = list(x.shape)
    shape[dim] *= 2
    out = _empty_like_layout(x, tuple(shape))
    out[at(0)] = x[at(0)]
    out[at(slice(2, None, 2))] = torch.lerp(x[at(slice(1, None))], x[at(slice(None, -1))], 0.25)
    out[at(slice(1, -1, 2))] = torch.lerp(x[at(slice(None, -1))], x[at(slice(1, None))], 0.25)
    out[at(-1)] = x[at(-1)]
    return out


def upsample2x_stencil(x: torch.Tensor) -> torch.Tensor:
    """Exact bilinear x2 up-sampling (``align_corners=False``) from elementwise ops and slicing.

    Equals ``F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)`` up to float
    rounding: each output row/column is 0.75 of its source plus 0.25 of the neighbour on its side, with
    edge clamping, separably along H and W. Keeps x's memory layout (NCHW or channels_last) and its
    backward is elementwise too. (N, C, H, W) -> (N, C, 2H, 2W).
    """
    return _upsample2x_along(_upsample2x_along(x, 2), 3)


def _use_stencil(x: torch.Tensor) -> bool:
    if _upsample_mode == "auto":
        return x.device.type != "cpu"
    return _upsample_mode == "stencil"


def upsample_bilinear(x: torch.Tensor, size: Sequence[int]) -> torch.Tensor:
    """``F.interpolate(x, size, mode="bilinear", align_corners=False)``; an exact x2 goes through
    :func:`upsample2x_stencil` where :func:`set_upsample_mode` says so. (N, C, h, w) -> (N, C, *size)."""
    h, w = x.shape[-2:]
    if tuple(size) == (2 * h, 2 * w) and _use_stencil(x):
        return upsample2x_stencil(x)
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class Upsample2x(nn.Module):
    """Bilinear x2 up-sampling (``align_corners=False``), see :func:`upsample_bilinear`."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) -> (N, C, 2H, 2W)."""
        h, w = x.shape[-2:]
        return upsample_bilinear(x, (2 * h, 2 * w))


def scaled(width: int, multiplier: float) -> int:
    """Channel count `width` scaled by `multiplier`, at least 4."""
    return max(4, int(round(width * multiplier)))
