"""Building blocks of the Transporter and CLIPort networks, layer for layer as in the reference code.

Residual bottlenecks without batch norm or conv biases (the reference trains with ``batchnorm: False``),
bilinear x2 up-sampling with ``align_corners=True`` (``nn.UpsamplingBilinear2d``), the U-Net up-block
with its batch norms, and the per-sample batch norm those batch norms need (see
:class:`PerSampleBatchNorm2d`). The stream fusions are :mod:`cliport.models.fusion`'s.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn


class ConvBlock(nn.Module):
    """1x1 -> 3x3 (strided) -> 1x1 bottleneck plus a strided 1x1 projection shortcut, no biases."""

    def __init__(self, in_ch: int, filters: tuple[int, int, int], stride: int = 1, final_relu: bool = True) -> None:
        super().__init__()
        f1, f2, f3 = filters
        self.conv1 = nn.Conv2d(in_ch, f1, 1, bias=False)
        self.conv2 = nn.Conv2d(f1, f2, 3, stride=stride, padding=1, bias=False)
        self.conv3 = nn.Conv2d(f2, f3, 1, bias=False)
        self.shortcut = nn.Conv2d(in_ch, f3, 1, stride=stride, bias=False)
        self.final_relu = final_relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, in_ch, H, W) -> (N, f3, ceil(H / stride), ceil(W / stride))."""
        y = F.relu(self.conv1(x))
        y = F.relu(self.conv2(y))
        y = self.conv3(y) + self.shortcut(x)
        return F.relu(y) if self.final_relu else y


class IdentityBlock(nn.Module):
    """1x1 -> 3x3 -> 1x1 bottleneck added to its own input (input width = output width), no biases."""

    def __init__(self, ch: int, filters: tuple[int, int], final_relu: bool = True) -> None:
        super().__init__()
        f1, f2 = filters
        self.conv1 = nn.Conv2d(ch, f1, 1, bias=False)
        self.conv2 = nn.Conv2d(f1, f2, 3, padding=1, bias=False)
        self.conv3 = nn.Conv2d(f2, ch, 1, bias=False)
        self.final_relu = final_relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, ch, H, W) -> (N, ch, H, W)."""
        y = F.relu(self.conv1(x))
        y = F.relu(self.conv2(y))
        y = self.conv3(y) + x
        return F.relu(y) if self.final_relu else y


class ResidualStage(nn.Sequential):
    """A conv block followed by an identity block, both `width` wide (the reference's stage pair)."""

    def __init__(self, in_ch: int, width: int, stride: int = 1) -> None:
        super().__init__(
            ConvBlock(in_ch, (width, width, width), stride=stride),
            IdentityBlock(width, (width, width)),
        )


class HeadStage(nn.Sequential):
    """Output stage: conv block and identity block with `hidden`-wide bottlenecks, no final ReLU."""

    def __init__(self, in_ch: int, hidden: int, out_ch: int) -> None:
        super().__init__(
            ConvBlock(in_ch, (hidden, hidden, out_ch), final_relu=False),
            IdentityBlock(out_ch, (hidden, hidden), final_relu=False),
        )


def upsample2x(x: torch.Tensor) -> torch.Tensor:
    """Bilinear x2 up-sampling with ``align_corners=True``, the reference's ``nn.UpsamplingBilinear2d``
    and U-Net ``Up``. (N, C, H, W) -> (N, C, 2H, 2W)."""
    return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=True)


def resize(x: torch.Tensor, size: Sequence[int]) -> torch.Tensor:
    """Bilinear resize with ``align_corners=False`` (``F.interpolate``'s default mode, which the reference
    uses to bring its 2x heads back to the input size). (N, C, h, w) -> (N, C, *size)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class Upsample2x(nn.Module):
    """:func:`upsample2x` as a module."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) -> (N, C, 2H, 2W)."""
        return upsample2x(x)


class UpStage(nn.Sequential):
    """A :class:`ResidualStage` followed by x2 up-sampling (the reference's decoder ``layerN``)."""

    def __init__(self, in_ch: int, width: int) -> None:
        super().__init__(ResidualStage(in_ch, width), Upsample2x())


class PerSampleBatchNorm2d(nn.BatchNorm2d):
    """Batch norm that always normalises with the statistics of one sample's images, in training and
    in eval mode alike.

    The reference trains at batch size 1 and acts without ``.eval()``, so its U-Net batch norms always
    normalise with each call's own statistics: one image for the pick and key nets, the 36 rotated
    crops of one sample for the query net. Here a call may hold several samples (training batches,
    ``act_batch``): the images are split into groups of ``samples_per_group`` consecutive images
    (1 for pick and key; ``n_rotations`` for the query net, whose crops come sample-major: its
    :class:`~cliport.models.heads.PlaceHead` sets that), and each
    group is normalised by its own per-channel mean and biased variance. A batch of 8 therefore trains
    like 8 reference steps and batch-mates never influence each other's outputs. The running
    statistics are never read; in training mode they are updated as the reference's sequence of
    batch-1 steps would update them, so that state dicts keep the reference's meaning.
    """

    def __init__(self, num_features: int, samples_per_group: int = 1) -> None:
        super().__init__(num_features)
        self.samples_per_group = samples_per_group

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, samples_per_group={self.samples_per_group}"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) with N a multiple of ``samples_per_group`` -> (N, C, H, W)."""
        n, c, h, w = x.shape
        size = self.samples_per_group
        if n % size:
            raise ValueError(f"{n} images do not split into groups of {size} (one group per sample)")
        groups = n // size
        # Group g's images become the batch of one channel block of a single batch_norm call.
        grouped = x.reshape(groups, size, c, h, w).transpose(0, 1).reshape(size, groups * c, h, w)
        running = (self.running_mean, self.running_var) if self.training else (None, None)
        mean = running[0].repeat(groups) if running[0] is not None else None
        var = running[1].repeat(groups) if running[1] is not None else None
        momentum = self._momentum() if mean is not None else 0.0  # read only when running statistics update
        out = F.batch_norm(
            grouped, mean, var, self.weight.repeat(groups), self.bias.repeat(groups), True, momentum, self.eps
        )
        if mean is not None and var is not None:
            self._update_running(mean, var, groups)
        return out.reshape(size, groups, c, h, w).transpose(0, 1).reshape(n, c, h, w)

    @torch.no_grad()
    def _update_running(self, mean: torch.Tensor, var: torch.Tensor, groups: int) -> None:
        """Turns the groups' parallel updates r_g = (1 - m) r + m s_g into the sequential result
        (1 - m)^G r + sum_g (1 - m)^(G - 1 - g) m s_g of G batch-1 steps."""
        keep = 1.0 - self._momentum()
        weights = keep ** torch.arange(groups - 1, -1, -1, dtype=mean.dtype, device=mean.device)
        for running, parallel in ((self.running_mean, mean), (self.running_var, var)):
            assert running is not None  # _update_running is only called with running statistics
            steps = parallel.view(groups, -1) - keep * running  # m * s_g
            running.mul_(keep**groups).add_((weights[:, None] * steps).sum(0))
        if self.num_batches_tracked is not None:
            self.num_batches_tracked.add_(groups)

    def _momentum(self) -> float:
        if self.momentum is None:  # a cumulative average has no per-group weights to fold
            raise ValueError("PerSampleBatchNorm2d needs a momentum (momentum=None is not supported)")
        return self.momentum


class DoubleConv(nn.Sequential):
    """(3x3 conv -> batch norm -> ReLU) x 2, the reference U-Net's block (convs with biases)."""

    def __init__(self, in_ch: int, out_ch: int, mid_ch: int) -> None:
        super().__init__(
            nn.Conv2d(in_ch, mid_ch, 3, padding=1),
            PerSampleBatchNorm2d(mid_ch),
            nn.ReLU(inplace=True),
            nn.Conv2d(mid_ch, out_ch, 3, padding=1),
            PerSampleBatchNorm2d(out_ch),
            nn.ReLU(inplace=True),
        )


class _ConvOverFrozenSkip(torch.autograd.Function):
    """``conv(cat([skip, x]))`` whose backward leaves out the gradient of ``skip``, which needs none (a frozen
    encoder's features).

    Autograd would compute the input gradient of the whole concatenation and drop the skip's part: in the
    CLIPort decoders' up-blocks the skip is 1024, 512 or 256 of the conv's 1152, 576 or 288 input channels (at
    every width; the decoder's own channels shrink with it), so about 45 % of the conv's backward went to a
    gradient nobody reads. The forward and the weight and bias gradients are the same calls as plain autograd's
    (bitwise the same values); the input gradient of ``x`` comes from a conv backward over ``x`` and its
    slice of the weight, which sums the same products and may round differently (~3e-7 relative, measured).

    With ``index`` (N,), the skip holds D distinct images and sample n reads ``skip[index[n]]``
    (:mod:`~cliport.models.distinct_images`): the skip's share of the conv runs once per distinct image,
    ``conv(skip, W_skip)[index] + conv(x, W_x)``, and its weight gradient once over the repeats' summed
    gradients. The same sums of products in another order (float rounding apart).
    """

    @staticmethod
    def forward(
        ctx: Any,
        skip: torch.Tensor,
        x: torch.Tensor,
        weight: torch.Tensor,
        bias: torch.Tensor | None,
        settings: tuple[tuple[int, int], tuple[int, int], tuple[int, int], int],
        index: torch.Tensor | None = None,
    ) -> torch.Tensor:
        c = skip.shape[1]
        ctx.skip_channels = c
        ctx.settings = settings
        ctx.has_bias = bias is not None
        if index is None:
            joined = torch.cat([skip, x], dim=1)
            ctx.save_for_backward(joined, weight)
            return F.conv2d(joined, weight, bias, *settings)
        skip_weight, x_weight = weight[:, :c].contiguous(), weight[:, c:].contiguous()
        ctx.save_for_backward(skip, x, skip_weight, x_weight, index)
        shared = F.conv2d(skip, skip_weight, None, *settings)
        return F.conv2d(x, x_weight, bias, *settings) + shared.index_select(0, index)

    @staticmethod
    def backward(
        ctx: Any, grad: torch.Tensor
    ) -> tuple[None, torch.Tensor, torch.Tensor, torch.Tensor | None, None, None]:
        c = ctx.skip_channels
        stride, padding, dilation, groups = ctx.settings
        conv_backward = torch.ops.aten.convolution_backward

        def backward_of(g, inp, w, wanted):  # type: ignore[no-untyped-def]  # aten's untyped op
            bias_sizes = [w.shape[0]] if wanted[2] else None
            return conv_backward(g, inp, w, bias_sizes, stride, padding, dilation, False, [0, 0], groups, wanted)

        if len(ctx.saved_tensors) == 2:
            joined, weight = ctx.saved_tensors
            _, grad_weight, grad_bias = backward_of(grad, joined, weight, [False, True, ctx.has_bias])
            grad_x, _, _ = backward_of(grad, joined[:, c:], weight[:, c:].contiguous(), [True, False, False])
        else:
            skip, x, skip_weight, x_weight, index = ctx.saved_tensors
            summed = grad.new_zeros((skip.shape[0], *grad.shape[1:])).index_add_(0, index, grad)
            _, skip_grad, _ = backward_of(summed, skip, skip_weight, [False, True, False])
            grad_x, x_grad, grad_bias = backward_of(grad, x, x_weight, [True, True, ctx.has_bias])
            grad_weight = torch.cat([skip_grad, x_grad], dim=1)
        return None, grad_x, grad_weight, grad_bias if ctx.has_bias else None, None, None


class UpBlock(nn.Module):
    """U-Net up-block: x2 up-sampling (``align_corners=True``), zero-pad to the skip's size, concatenate
    [skip, up] and a :class:`DoubleConv` from ``in_ch`` (= both widths) through ``in_ch // 2`` to ``out_ch``.

    When the skip needs no gradient (a frozen encoder's features) and autocast is off, training's backward
    skips the skip's input gradient, and a skip of distinct images (``index``) is convolved once per image
    (:class:`_ConvOverFrozenSkip`)."""

    def __init__(self, in_ch: int, out_ch: int, mid_ch: int | None = None) -> None:
        super().__init__()
        self.conv = DoubleConv(in_ch, out_ch, in_ch // 2 if mid_ch is None else mid_ch)

    def forward(self, x: torch.Tensor, skip: torch.Tensor, index: torch.Tensor | None = None) -> torch.Tensor:
        """(N, c, h, w), skip (N, in_ch - c, H, W) with H, W >= 2h, 2w -> (N, out_ch, H, W). ``index`` (N,): the
        skip holds D distinct images instead, (D, in_ch - c, H, W), and sample n reads ``skip[index[n]]``."""
        x = upsample2x(x)
        dh, dw = skip.shape[-2] - x.shape[-2], skip.shape[-1] - x.shape[-1]
        if dh or dw:
            x = F.pad(x, [dw // 2, dw - dw // 2, dh // 2, dh - dh // 2])
        first = self.conv[0]
        frozen_skip = not skip.requires_grad and (index is not None or (x.requires_grad and torch.is_grad_enabled()))
        if not frozen_skip or torch.is_autocast_enabled(x.device.type) or first.padding_mode != "zeros":
            skip = skip if index is None else skip.index_select(0, index)
            return self.conv(torch.cat([skip, x], dim=1))
        settings = (first.stride, first.padding, first.dilation, first.groups)
        y = _ConvOverFrozenSkip.apply(skip, x, first.weight, first.bias, settings, index)
        for layer in list(self.conv)[1:]:
            y = layer(y)
        return y


def scaled(width: int, multiplier: float) -> int:
    """Channel count `width` scaled by `multiplier`, at least 4."""
    return max(4, int(round(width * multiplier)))
