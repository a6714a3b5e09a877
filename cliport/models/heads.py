"""Pick ("attention") and place ("transport") heads wrapped around any net of the streams module.

Rotation convention (place): bin k stands for the relative world yaw theta_k = k * 2*pi / n_rotations,
counter-clockwise about +z. Image rows run along +y and columns along +x, so a pixel offset (du, dv) is
the world vector (dx, dy) = (dv, du). The query for bin k is the neighbourhood of the pick pixel as it
looks after rotating it by theta_k in world yaw: crop_k(o) = image(pick + R(-theta_k) o), with R acting
on (x, y) = (column, row) offsets. It therefore matches the place neighbourhood of an object that is
placed theta_k (counter-clockwise) relative to how it was picked, and decoding bin k gives that yaw.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.correlation import fft_cross_correlation


class PickHead(nn.Module):
    """Pads the input to a square, runs a 1-channel net and crops back: logits over all pick pixels."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net
        # The layout the net's input is given in (channels_last on CUDA, see PickPlaceAgent.optimize_for_device).
        self.input_memory_format = torch.contiguous_format

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (B, 6, H, W), sentence (B, sentence_dim) or None -> logits (B, H, W)."""
        h, w = x.shape[-2:]
        side = max(h, w)
        top, left = (side - h) // 2, (side - w) // 2
        padded = F.pad(x, (left, side - w - left, top, side - h - top))
        padded = padded.contiguous(memory_format=self.input_memory_format)
        logits = self.net(padded, sentence)
        return logits[:, 0, top : top + h, left : left + w]


def rotated_crop_grid(
    pick_pix: torch.Tensor, n_rotations: int, crop_size: int, padded_hw: tuple[int, int], pad: int
) -> torch.Tensor:
    """Sampling grid of the rotated query crops for ``grid_sample(..., align_corners=True)``.

    pick_pix (B, 2) as (u, v) in the unpadded image -> grid (B, n_rotations * crop, crop, 2), in which
    rows r * crop .. (r + 1) * crop - 1 hold the crop of rotation bin r (see the module docstring).
    """
    device = pick_pix.device
    half = crop_size // 2
    offsets = torch.arange(crop_size, device=device, dtype=torch.float32) - half
    du, dv = torch.meshgrid(offsets, offsets, indexing="ij")  # (crop, crop)
    theta = torch.arange(n_rotations, device=device, dtype=torch.float32) * (2 * math.pi / n_rotations)
    cos, sin = torch.cos(theta)[:, None, None], torch.sin(theta)[:, None, None]
    # R(-theta) applied to the (x, y) = (dv, du) offset.
    sample_v = cos * dv + sin * du
    sample_u = -sin * dv + cos * du
    centre = pick_pix.float() + pad
    u = centre[:, 0, None, None, None] + sample_u[None]
    v = centre[:, 1, None, None, None] + sample_v[None]
    hp, wp = padded_hw
    grid = torch.stack([2 * v / (wp - 1) - 1, 2 * u / (hp - 1) - 1], dim=-1)  # (B, R, crop, crop, 2)
    return grid.reshape(pick_pix.shape[0], n_rotations * crop_size, crop_size, 2)


class PlaceHead(nn.Module):
    """Transporter place head: rotated query crops around the pick pixel correlated with a key map."""

    def __init__(self, key_net: nn.Module, query_net: nn.Module, crop_size: int, n_rotations: int) -> None:
        super().__init__()
        if crop_size % 2:
            raise ValueError("crop_size must be even")
        self.key_net = key_net
        self.query_net = query_net
        self.crop_size = crop_size
        self.n_rotations = n_rotations
        self.input_memory_format = torch.contiguous_format

    def rotation_bin(self, relative_yaw: torch.Tensor) -> torch.Tensor:
        """Bin of a relative place yaw (place yaw - pick yaw, radians), (B,) float -> (B,) int64:
        the nearest k with k * 2*pi / n_rotations, modulo n_rotations."""
        step = 2 * math.pi / self.n_rotations
        return torch.round(torch.remainder(relative_yaw.double(), 2 * math.pi) / step).long() % self.n_rotations

    def query_crops(self, padded: torch.Tensor, pick_pix: torch.Tensor) -> torch.Tensor:
        """Padded raw (B, C, H + crop, W + crop), pick (B, 2) -> crops (B * R, C, crop, crop), bin-major
        within each sample."""
        b, c = padded.shape[:2]
        grid = rotated_crop_grid(pick_pix, self.n_rotations, self.crop_size, padded.shape[-2:], self.crop_size // 2)
        crops = F.grid_sample(padded, grid.to(padded.dtype), mode="bilinear", align_corners=True)
        crops = crops.reshape(b, c, self.n_rotations, self.crop_size, self.crop_size)
        crops = crops.transpose(1, 2).reshape(b * self.n_rotations, c, self.crop_size, self.crop_size)
        return crops.contiguous(memory_format=self.input_memory_format)

    def forward(self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (B, 6, H, W), pick (B, 2) int (u, v), sentence (B, sentence_dim) or None -> logits (B, R, H, W)."""
        b, _, h, w = x.shape
        pad = self.crop_size // 2
        padded = F.pad(x, (pad, pad, pad, pad)).contiguous(memory_format=self.input_memory_format)
        key = self.key_net(padded, sentence)
        query_sentence = None
        if sentence is not None:
            # Each sample's sentence for its R crops; unlike repeat_interleave, expand + reshape never
            # synchronises with the host, so the place forward can be captured in a CUDA graph.
            query_sentence = sentence[:, None].expand(-1, self.n_rotations, -1).reshape(b * self.n_rotations, -1)
        query = self.query_net(self.query_crops(padded, pick_pix), query_sentence)
        kernels = query.reshape(b, self.n_rotations, *query.shape[1:])
        return fft_cross_correlation(key, kernels)[..., :h, :w]
