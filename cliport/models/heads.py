"""Pick ("attention") and place ("transport") heads wrapped around any of the nets (see :mod:`cliport.models`).

They reproduce the reference's ``Attention`` and ``Transport`` (cliport/models/core/attention.py,
transport.py) and their stream variants around whichever nets an agent gives them.

Rotation convention (place), the reference CLIPort's: the query of bin k is cut from the padded input
rotated by k * 360 / n_rotations degrees about the pick pixel, counter-clockwise as the image is shown
(rows downwards), with kornia 0.4.1's ``warp_affine`` pixel convention (see :mod:`cliport.models.rotation`).
Rows run along world +y and columns along +x, so a rotation that is counter-clockwise on screen turns
the scene by a negative world yaw: bin k stands for the relative world yaw -k * 2*pi / n_rotations
(counter-clockwise about +z), which :meth:`PlaceHead.bin_yaw` gives and :meth:`PlaceHead.rotation_bin`
inverts.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models import rotation
from cliport.models.blocks import PerSampleBatchNorm2d
from cliport.models.correlation import transport_correlation
from cliport.models.encoder_net import EncoderNet

#: Output channels of the place head's key and query nets (the reference's transport ``output_dim``).
PLACE_FEATURES = 3


def shrink_map(x: torch.Tensor, map_scale: float) -> torch.Tensor:
    """(B, C, H, W) -> (B, C, round(H * s), round(W * s)) by area averaging; unchanged at ``map_scale`` 1."""
    if map_scale == 1.0:
        return x
    h, w = x.shape[-2:]
    return F.interpolate(x, size=(round(h * map_scale), round(w * map_scale)), mode="area")


def grow_logits(logits: torch.Tensor, size: tuple[int, ...]) -> torch.Tensor:
    """(B, K, h, w) -> (B, K, H, W) bilinearly (pixel centres aligned); unchanged where already (H, W)."""
    if tuple(logits.shape[-2:]) == tuple(size):
        return logits
    return F.interpolate(logits, size=size, mode="bilinear", align_corners=False)


def rotation_bin(relative_yaw: torch.Tensor, n_rotations: int) -> torch.Tensor:
    """Bin of a relative place yaw (place yaw - pick yaw, radians), (B,) float -> (B,) int64: the nearest k
    with -k * 2*pi / n_rotations, modulo n_rotations (the reference's labels; see :class:`PlaceHead`)."""
    step = 2 * math.pi / n_rotations
    return torch.round(-relative_yaw.double() / step).long() % n_rotations


def pad_square(x: torch.Tensor) -> tuple[torch.Tensor, tuple[int, int]]:
    """(B, C, h, w) -> zero-padded to (B, C, s, s), s = max(h, w), centred, and the (top, left) of the
    original inside it."""
    h, w = x.shape[-2:]
    side = max(h, w)
    top, left = (side - h) // 2, (side - w) // 2
    return F.pad(x, (left, side - w - left, top, side - h - top)), (top, left)


class PickHead(nn.Module):
    """Pads the input to a square, runs a 1-channel net and crops back: logits over all pick pixels.

    ``map_scale`` < 1 (not the reference's; a CPU option) runs the net on the map shrunk by that factor
    (area averaging) and grows its logits back bilinearly, so the output keeps the input's pixels.
    """

    def __init__(self, net: nn.Module, map_scale: float = 1.0) -> None:
        super().__init__()
        self.net = net
        self.map_scale = map_scale
        # The layout the net's input is given in (channels_last on CUDA, see PickPlaceAgent.optimize_for_device).
        self.input_memory_format = torch.contiguous_format

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (B, 6, H, W), sentence (B, sentence_dim) or None -> logits (B, H, W).

        As the reference, the padded input and the logits are rotated by 0 degrees about the centre with
        kornia's convention, which resamples them by float32 rounding (see :mod:`cliport.models.rotation`).
        """
        size = x.shape[-2:]
        x = shrink_map(x, self.map_scale)
        h, w = x.shape[-2:]
        square, (top, left) = pad_square(x)
        pivot = (square.shape[-1] // 2, square.shape[-1] // 2)
        padded = rotation.warp(square, 0.0, pivot)
        logits = self.net(padded.contiguous(memory_format=self.input_memory_format), sentence)
        logits = rotation.warp(logits[:, :1], 0.0, pivot)
        return grow_logits(logits[:, :, top : top + h, left : left + w], size)[:, 0]


def _group_by_sample(net: nn.Module, images_per_sample: int) -> None:
    """Tell a net that its batches hold ``images_per_sample`` consecutive images per sample (a query net's
    rotated crops): its per-sample batch norms and its encoder-norm training group them so."""
    for module in net.modules():
        if isinstance(module, (PerSampleBatchNorm2d, EncoderNet)):
            module.samples_per_group = images_per_sample


class PlaceHead(nn.Module):
    """Transporter place head: rotated query crops around the pick pixel correlated with a key map.

    The query net sees ``n_rotations`` crops per sample; the head sets its ``samples_per_group`` (see
    :class:`~cliport.models.blocks.PerSampleBatchNorm2d`) to that. ``map_scale`` < 1 works as in
    :class:`PickHead`, with crops of ``crop_size * map_scale`` pixels of the shrunk map (the same extent on
    the table) around the pick pixel's cell there.
    """

    def __init__(
        self, key_net: nn.Module, query_net: nn.Module, crop_size: int, n_rotations: int, map_scale: float = 1.0
    ) -> None:
        super().__init__()
        crop = round(crop_size * map_scale)
        if crop % 2 or crop < 2 or abs(crop - crop_size * map_scale) > 1e-6:
            raise ValueError(f"crop_size x map_scale must be an even whole number, got {crop_size} x {map_scale}")
        self.key_net = key_net
        self.query_net = query_net
        self.crop_size = crop  # in the net's map pixels
        self.map_scale = map_scale
        self.n_rotations = n_rotations
        _group_by_sample(query_net, n_rotations)
        self.input_memory_format = torch.contiguous_format
        # Another layout for the key net's input only (None: input_memory_format). The reference's key net reads
        # a permuted (H, W, C) array, i.e. channels_last: float32 convolutions of the two layouts round
        # differently, and this net's early-layer gradients differ by up to 3 % between them (the training
        # parity test runs ours in the reference's layout). Not the CPU default: PyTorch 2.14's channels_last
        # convolution backward corrupts the heap on the CPU at width 0.125.
        self.key_memory_format: torch.memory_format | None = None

    def rotation_bin(self, relative_yaw: torch.Tensor) -> torch.Tensor:
        """Bin of a relative place yaw (place yaw - pick yaw, radians), (B,) float -> (B,) int64: the
        nearest k with -k * 2*pi / n_rotations, modulo n_rotations (the reference's labels)."""
        return rotation_bin(relative_yaw, self.n_rotations)

    def bin_yaw(self, k: int) -> float:
        """The relative world yaw (radians, in (-2*pi, 0]) that rotation bin ``k`` stands for."""
        return -k * 2 * math.pi / self.n_rotations

    def query_crops(self, padded: torch.Tensor, pick_pix: torch.Tensor) -> torch.Tensor:
        """Padded raw (B, C, H + crop, W + crop), pick (B, 2) -> crops (B * R, C, crop, crop), bin-major
        within each sample."""
        crops = rotation.rotated_crops(padded, pick_pix + self.crop_size // 2, self.n_rotations, self.crop_size)
        return crops.contiguous(memory_format=self.input_memory_format)

    def forward(self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (B, 6, H, W), pick (B, 2) int (u, v), sentence (B, sentence_dim) or None -> logits (B, R, H, W)."""
        size = x.shape[-2:]
        if self.map_scale != 1.0:
            x = shrink_map(x, self.map_scale)
            # The pick's cell on the shrunk map; clamped with Python bounds (no host tensor: CUDA-graph safe).
            cell = (pick_pix * self.map_scale).floor().long()
            pick_pix = torch.stack((cell[:, 0].clamp(max=x.shape[-2] - 1), cell[:, 1].clamp(max=x.shape[-1] - 1)), 1)
        b = x.shape[0]
        pad = self.crop_size // 2
        padded = F.pad(x, (pad, pad, pad, pad)).contiguous(memory_format=self.input_memory_format)
        key_layout = self.key_memory_format or self.input_memory_format
        key = self.key_net(padded.contiguous(memory_format=key_layout), sentence)
        query_sentence = None
        if sentence is not None:
            # Each sample's sentence for its R crops; unlike repeat_interleave, expand + reshape never
            # synchronises with the host, so the place forward can be captured in a CUDA graph.
            query_sentence = sentence[:, None].expand(-1, self.n_rotations, -1).reshape(b * self.n_rotations, -1)
        query = self.query_net(self.query_crops(padded, pick_pix), query_sentence)
        kernels = query.reshape(b, self.n_rotations, *query.shape[1:])
        return grow_logits(transport_correlation(key, kernels), size)
