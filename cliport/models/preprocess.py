"""Network inputs: RGB + height repeated 3x, and the Transporter-stream normalisation."""

from __future__ import annotations

import numpy as np
import torch

# Transporter-stream statistics (Ravens): RGB scaled to [0, 1], heights in metres.
COLOR_MEAN = 0.18877631
COLOR_STD = 0.07276466
HEIGHT_MEAN = 0.00509261
HEIGHT_STD = 0.00903967
IN_CHANNELS = 6


def raw_input(color: torch.Tensor | np.ndarray, height: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Stack RGB (in [0, 1]) and the height (metres, repeated 3x) channels-first.

    color (B, H, W, 3) uint8 and height (B, H, W) float -> (B, 6, H, W) float32.
    Unbatched inputs (H, W, 3) / (H, W) give (1, 6, H, W).
    """
    color = torch.as_tensor(color)
    height = torch.as_tensor(height)
    if color.dim() == 3:
        color, height = color[None], height[None]
    rgb = color.permute(0, 3, 1, 2).float() / 255.0
    h = height.float()[:, None].expand(-1, 3, -1, -1)
    return torch.cat([rgb, h], dim=1)


def transporter_normalize(x: torch.Tensor) -> torch.Tensor:
    """Normalise a raw (N, 6, H, W) input (RGB in [0, 1], heights in metres) with the Ravens statistics."""
    rgb = (x[:, :3] - COLOR_MEAN) / COLOR_STD
    h = (x[:, 3:] - HEIGHT_MEAN) / HEIGHT_STD
    return torch.cat([rgb, h], dim=1)
