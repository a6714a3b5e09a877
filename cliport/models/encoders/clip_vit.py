"""The ViT adapter of the frozen open_clip model: a ViT tower's patch tokens as the five trunk levels a decoder reads.

A ViT has one resolution (stride 16 for ViT-B-16); the decoders and laterals need the strides 4, 4, 8, 16,
32 of a ResNet trunk (stem, layer1..layer4). :func:`vit_levels` runs the ViT on the image at its own size
and resamples the patch tokens of four blocks spread evenly through the depth to those strides.
Parameter-free: the model's weights are used as they are.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F

#: The strides the ViT adapter resamples its four chosen blocks' patch tokens to (layer1..layer4).
_VIT_LEVEL_STRIDES = (4, 8, 16, 32)


def vit_block_indices(depth: int) -> tuple[int, int, int, int]:
    """0-based indices of the four blocks the ViT levels come from: the ends of the four quarters of the depth.

    12 blocks -> (2, 5, 8, 11) (blocks 3, 6, 9, 12); 24 -> (5, 11, 17, 23); 32 -> (7, 15, 23, 31).
    """
    a, b, c, d = (max(1, (depth * k + 2) // 4) - 1 for k in (1, 2, 3, 4))
    return a, b, c, d


def _resized_pos_embed(pos: torch.Tensor, old_grid: tuple[int, int], new_grid: tuple[int, int]) -> torch.Tensor:
    """A ViT's position embeddings (1 + gh * gw, C) for another token grid: the class token's row kept, the
    (gh, gw) grid of the others bilinearly resized to ``new_grid`` -> (1 + new_h * new_w, C). A new tensor;
    the model's parameter is not touched."""
    if tuple(old_grid) == tuple(new_grid):
        return pos
    channels = pos.shape[-1]
    grid = pos[1:].float().reshape(1, old_grid[0], old_grid[1], channels).permute(0, 3, 1, 2)
    grid = F.interpolate(grid, size=new_grid, mode="bilinear", align_corners=False)
    return torch.cat([pos[:1], grid.permute(0, 2, 3, 1).reshape(-1, channels).to(pos.dtype)])


def _resample_to(grid: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(N, C, h, w) -> (N, C, *size): identity, k x k average pooling when (h, w) = k * size, else bilinear."""
    (h, w), (th, tw) = grid.shape[-2:], size
    if (h, w) == (th, tw):
        return grid
    if h % th == 0 and w % tw == 0 and h // th == w // tw:
        return F.avg_pool2d(grid, h // th)
    return F.interpolate(grid, size=size, mode="bilinear", align_corners=False)


def vit_levels(visual: Any, block_indices: tuple[int, int, int, int], x: torch.Tensor) -> list[torch.Tensor]:
    """Five trunk levels of a ViT tower (open_clip's ``VisionTransformer``), parameter-free, from normalised
    images (N, 3, H, W); ``block_indices``: the four blocks read (:func:`vit_block_indices` of the depth).

    1. Token grid: (gh, gw) = (H / p, W / p) for the patch size p (rounded, and the image bilinearly
       resized to (gh * p, gw * p) when p does not divide H or W, e.g. p = 14). The ViT runs on the
       image at its own size: the position embeddings' grid (224 / p squared) is bilinearly resized to
       (gh, gw), the class token's embedding kept as it is (:func:`_resized_pos_embed`; the model's
       weights are not changed).
    2. Blocks: the patch tokens (class token dropped, no final LayerNorm) after the four blocks ending
       the four quarters of the depth (:func:`vit_block_indices`: blocks 3, 6, 9, 12 of ViT-B's 12),
       each reshaped to (N, C, gh, gw). Evenly spaced blocks go from local, early features to the
       last block's semantic ones that CLIP's embedding is read from, the way a ResNet's layer1..4 do
       (and as DPT reads ViT-B).
    3. Strides: the i-th block is resampled to stride (4, 8, 16, 32)[i], i.e. to (H / s, W / s):
       identity where the grid already has that size, k x k average pooling where it is k times
       larger, bilinear interpolation otherwise (p = 16: x4 and x2 bilinear up, identity, 2 x 2
       average pool).
    4. Levels: [stem, layer1, layer2, layer3, layer4] = [b1 at /4, b1 at /4, b2 at /8, b3 at /16,
       b4 at /32]: the stem is the first block's stride-4 map (the same tensor as layer1).

    Returns five (N, width, H / s, W / s) maps for the strides (4, 4, 8, 16, 32).
    """
    n, _, h, w = x.shape
    ph, pw = visual.patch_size
    gh, gw = max(1, round(h / ph)), max(1, round(w / pw))
    if (gh * ph, gw * pw) != (h, w):
        x = F.interpolate(x, size=(gh * ph, gw * pw), mode="bilinear", align_corners=False)
    tokens = visual.conv1(x).flatten(2).transpose(1, 2)  # (N, gh * gw, C)
    cls = visual.class_embedding.to(tokens.dtype).view(1, 1, -1).expand(n, 1, -1)
    pos = _resized_pos_embed(visual.positional_embedding, visual.grid_size, (gh, gw)).to(tokens.dtype)
    tokens = visual.ln_pre(visual.patch_dropout(torch.cat([cls, tokens], dim=1) + pos))
    _, blocks = visual.transformer.forward_intermediates(tokens, indices=list(block_indices), stop_early=True)
    grids = [b[:, 1:].transpose(1, 2).reshape(n, -1, gh, gw) for b in blocks]
    levels = [_resample_to(g, (h // s, w // s)) for g, s in zip(grids, _VIT_LEVEL_STRIDES, strict=True)]
    return [levels[0], *levels]
