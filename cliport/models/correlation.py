"""Cross-correlation of a key feature map with per-sample kernel banks, computed with FFTs."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def fft_cross_correlation(key: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Valid cross-correlation of each sample's key map with its own bank of kernels.

    out[b, r, u, v] = sum_{c, i, j} key[b, c, u + i, v + j] * kernels[b, r, c, i, j], the same as
    ``F.conv2d(key[b:b+1], kernels[b])`` (PyTorch's conv2d is a correlation). The FFT length equals the
    key size, so the circular correlation agrees with the linear one on every valid output and nothing
    wraps around. Always computed in float32.

    Args:
        key: (B, C, H, W).
        kernels: (B, R, C, h, w) with h <= H and w <= W.
    Returns:
        (B, R, H - h + 1, W - w + 1).
    """
    b, c, height, width = key.shape
    kh, kw = kernels.shape[-2:]
    with torch.autocast(device_type=key.device.type, enabled=False):
        key_f = torch.fft.rfft2(key.float(), s=(height, width))
        kernel_f = torch.fft.rfft2(kernels.float(), s=(height, width))
        spectrum = torch.einsum("bchw,brchw->brhw", key_f, kernel_f.conj())
        out = torch.fft.irfft2(spectrum, s=(height, width))
    return out[..., : height - kh + 1, : width - kw + 1]


def transport_correlation(key: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """The place logits of the reference's Transport: correlation of the padded key map with the query
    kernels, with the reference's resize.

    The reference computes ``conv2d(key, kernels, padding=crop / 2)``, of size (H + crop + 1, W + crop + 1)
    for a key padded by crop / 2 on each side, bilinearly resizes it (``align_corners=False``) to the
    key's size (H + crop, W + crop) and crops the padding, which blends neighbouring outputs by up to
    (H + crop)^-1 of a pixel per pixel of distance from the top-left corner. The resized values inside the
    crop only read outputs where the kernel lies inside the key map, i.e. the valid correlation, which is
    computed here with FFTs (:func:`fft_cross_correlation`) and zero-padded to the conv's size.

    Args:
        key: (B, C, H + crop, W + crop), the key net's output on the padded input.
        kernels: (B, R, C, crop, crop), the query net's outputs.
    Returns:
        (B, R, H, W).
    """
    kh, kw = kernels.shape[-2:]
    ph, pw = kh // 2, kw // 2
    hk, wk = key.shape[-2:]
    valid = fft_cross_correlation(key, kernels)  # (B, R, H + 1, W + 1)
    full = F.pad(valid, (pw, pw, ph, ph))  # the size of the padded conv2d's output
    resized = F.interpolate(full, size=(hk, wk), mode="bilinear", align_corners=False)
    return resized[..., ph : hk - ph, pw : wk - pw]


def direct_cross_correlation(key: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Reference implementation of :func:`fft_cross_correlation` with ``F.conv2d`` (slow; for tests).

    (B, C, H, W), (B, R, C, h, w) -> (B, R, H - h + 1, W - w + 1).
    """
    return torch.cat([F.conv2d(key[i : i + 1], kernels[i]) for i in range(key.shape[0])])
