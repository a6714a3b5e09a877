"""Image rotations as the reference CLIPort computes them: kornia 0.4.1's ``get_rotation_matrix2d`` and
``warp_affine``, reimplemented with the same float32 operations in the same order.

kornia maps pixels to [-1, 1] with ``2 / (size - 1)`` (the align-corners convention) but builds and
samples its grid with ``align_corners=False``. Its rotations are therefore not exact: about the pivot,
pixel offsets are scaled by (size - 1) / size before rotating and by size / (size - 1) after, per axis,
which moves the pixels of a 64-pixel crop of a 384 x 224 image by up to 0.17 px; and even a rotation by 0
resamples the image at positions off by float32 rounding (~1e-5 px). The reference rotates its pick
input and output by 0 and its place query crops by k * 360 / n_rotations degrees; the heads here do the
same, so that the logits agree to float precision.

The geometry runs in float32 even under autocast (bfloat16 has no matrix inverse, and its 8-bit mantissa
would move a sampling position by pixels), and a forward makes no host-to-device copy and no
synchronising check, so that it can be captured as a CUDA graph: the constants of an angle set, image size
and device are computed once and cached, and the pick's whole-image warp (fixed angle and pivot) is cached.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F

_PI = torch.tensor(math.pi)  # kornia's float32 pi


def _pixel_to_unit(height: int, width: int, device: torch.device) -> torch.Tensor:
    """kornia's ``normal_transform_pixel``: pixels to [-1, 1] with 2 / (size - 1), (3, 3) float32."""
    mat = torch.tensor([[1.0, 0.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]], device=device)
    mat[0, 0] = mat[0, 0] * 2.0 / (width - 1.0)
    mat[1, 1] = mat[1, 1] * 2.0 / (height - 1.0)
    return mat


@functools.lru_cache(maxsize=64)
def _angle_constants(
    angles_deg: tuple[float, ...], size: tuple[int, int], device: torch.device
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """cos (R,), sin (R,), the pixel-to-unit matrix (1, 3, 3), its inverse and 1.0, float32 on ``device``."""
    with torch.autocast(device.type, enabled=False):
        rad = torch.tensor(angles_deg).float().to(device) * _PI.to(device) / 180.0
        to_unit = _pixel_to_unit(*size, device)[None]
        return torch.cos(rad), torch.sin(rad), to_unit, torch.inverse(to_unit), torch.tensor(1.0, device=device)


def sampling_theta(angles_deg: tuple[float, ...], pivots: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """The ``affine_grid`` matrices with which kornia's ``warp_affine`` samples an image of ``size`` (H, W)
    rotated by each angle (degrees, counter-clockwise as shown with rows downwards) about each pivot.

    angles_deg: R angles; pivots (B, 2) as (row, col) -> (B, R, 2, 3) float32.
    """
    device = pivots.device
    b, r = pivots.shape[0], len(angles_deg)
    cos, sin, to_unit, unit_to_pixel, one = _angle_constants(tuple(float(a) for a in angles_deg), size, device)
    with torch.autocast(device.type, enabled=False):
        cos, sin = cos[None].expand(b, r), sin[None].expand(b, r)
        x = pivots[:, 1].float()[:, None]
        y = pivots[:, 0].float()[:, None]
        zeros, ones = torch.zeros_like(cos), torch.ones_like(cos)
        matrix = torch.stack(
            [
                torch.stack([cos, sin, (one - cos) * x - sin * y], -1),
                torch.stack([-sin, cos, sin * x + (one - cos) * y], -1),
                torch.stack([zeros, zeros, ones], -1),
            ],
            dim=-2,
        ).reshape(b * r, 3, 3)
        unit_from_unit = to_unit @ (matrix @ unit_to_pixel)
        # inv_ex: the same inverse without the error check that would synchronise with the host.
        return torch.linalg.inv_ex(unit_from_unit).inverse[:, :2, :].reshape(b, r, 2, 3)


@functools.lru_cache(maxsize=64)
def _warp_theta(angle_deg: float, pivot: tuple[int, int], size: tuple[int, int], device: torch.device) -> torch.Tensor:
    """``sampling_theta`` of one angle about one pivot, (1, 2, 3) float32 on ``device``."""
    pivots = torch.tensor([pivot], dtype=torch.float32, device=device)
    return sampling_theta((angle_deg,), pivots, size)[:, 0]


def _unit_coordinates(n: int, device: torch.device) -> torch.Tensor:
    """``affine_grid``'s pixel-centre coordinates along an axis of n pixels (align_corners=False)."""
    return torch.linspace(-1, 1, n, device=device) * (n - 1) / n


def warp(x: torch.Tensor, angle_deg: float, pivot: tuple[int, int]) -> torch.Tensor:
    """kornia's ``warp_affine(x, get_rotation_matrix2d(pivot, angle))``, the whole image.

    x (N, C, H, W) -> (N, C, H, W); pivot (row, col).
    """
    n, c, h, w = x.shape
    theta = _warp_theta(float(angle_deg), (int(pivot[0]), int(pivot[1])), (h, w), x.device).expand(n, 2, 3)
    with torch.autocast(x.device.type, enabled=False):
        grid = F.affine_grid(theta, [n, c, h, w], align_corners=False)
    return F.grid_sample(x, grid.to(x.dtype), mode="bilinear", padding_mode="zeros", align_corners=False)


def rotated_crops(x: torch.Tensor, pivots: torch.Tensor, n_rotations: int, crop_size: int) -> torch.Tensor:
    """The reference's place query crops: for each sample and each k < ``n_rotations``, the ``crop_size``
    square around the pivot of the image rotated by k * 360 / n_rotations degrees about the pivot.

    Only the cropped pixels are sampled; their grid is the same as kornia's for the whole image (same
    coordinates, same matrix product). x (B, C, H, W), pivots (B, 2) int (row, col), at least crop_size / 2
    from the border -> (B * R, C, crop, crop), rotation-minor.
    """
    b, c, h, w = x.shape
    device = x.device
    angles = tuple(k * 2 * 180 / n_rotations for k in range(n_rotations))
    theta = sampling_theta(angles, pivots, (h, w))  # (B, R, 2, 3)
    with torch.autocast(device.type, enabled=False):
        offsets = torch.arange(crop_size, device=device) - crop_size // 2
        rows = pivots[:, 0:1].long() + offsets  # (B, crop)
        cols = pivots[:, 1:2].long() + offsets
        ys = _unit_coordinates(h, device)[rows][:, :, None].expand(b, crop_size, crop_size)
        xs = _unit_coordinates(w, device)[cols][:, None, :].expand(b, crop_size, crop_size)
        base = torch.stack([xs, ys, torch.ones_like(xs)], dim=-1).reshape(b, 1, crop_size * crop_size, 3)
        base = base.expand(b, n_rotations, -1, -1).reshape(b * n_rotations, -1, 3)
        grid = base.bmm(theta.reshape(b * n_rotations, 2, 3).transpose(1, 2))  # (B * R, crop * crop, 2)
        grid = grid.reshape(b, n_rotations * crop_size, crop_size, 2)
    crops = F.grid_sample(x, grid.to(x.dtype), mode="bilinear", padding_mode="zeros", align_corners=False)
    crops = crops.reshape(b, c, n_rotations, crop_size, crop_size).transpose(1, 2)
    return crops.reshape(b * n_rotations, c, crop_size, crop_size)
