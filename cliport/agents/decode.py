"""Between action poses and the heads' maps: training targets from poses (pixels and rotation bins), and
actions from logits (the argmax pixels, the rotation bin and the poses they stand for), the acting half of
``PickPlaceAgent.act_batch`` (:func:`act_input`, :func:`decide`).

Pixels are (row, col) = (u, v) of the top-down image, whose rows run along the world's y axis and columns
along x (:mod:`cliport.env.heightmap`); rotation bins are the place head's, whose yaws it gives.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from cliport.env.heightmap import BOUNDS, PIXEL_SIZE, pix_to_xyz
from cliport.env.transforms import yaw_to_quat
from cliport.models.heads import rotation_bin
from cliport.models.preprocess import raw_input

#: ``(raw input, sentence) -> pick logits`` and ``(raw input, pick pixels, sentence) -> place logits``.
PickForward = Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor]
PlaceForward = Callable[[torch.Tensor, torch.Tensor, torch.Tensor | None], torch.Tensor]


def pose_pixels(pose: torch.Tensor, hw: tuple[int, ...]) -> torch.Tensor:
    """Poses (B, 7) (xyz + quaternion xyzw, world frame of the image) -> their pixels (B, 2) (row, col;
    int64, clamped to the (H, W) image)."""
    u = torch.round((pose[:, 1] - BOUNDS[1, 0]) / PIXEL_SIZE).clamp(0, hw[0] - 1)
    v = torch.round((pose[:, 0] - BOUNDS[0, 0]) / PIXEL_SIZE).clamp(0, hw[1] - 1)
    return torch.stack([u, v], dim=1).long()


def pose_yaw(pose: torch.Tensor) -> torch.Tensor:
    """Poses (B, 7) -> the z angles (B,) of their quaternions (quat_to_yaw: the reference's labels' angle)."""
    x, y, z, w = pose[:, 3], pose[:, 4], pose[:, 5], pose[:, 6]
    return torch.atan2(2 * (x * y + w * z), 1 - 2 * (x * x + z * z))


def action_targets(
    pose0: torch.Tensor | np.ndarray, pose1: torch.Tensor | np.ndarray, hw: tuple[int, int], n_rotations: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Training targets of pick and place poses (B, 7) (xyz + quaternion xyzw, world frame of the image), on
    the CPU in float64: pick pixel (B, 2), place pixel (B, 2) (row, col; int64, clamped to the (H, W) image)
    and the place head's rotation bin (B,) of the relative yaw (:func:`~cliport.models.heads.rotation_bin`)."""
    pose0 = torch.as_tensor(pose0, dtype=torch.float64)
    pose1 = torch.as_tensor(pose1, dtype=torch.float64)
    rotation = rotation_bin(pose_yaw(pose1) - pose_yaw(pose0), n_rotations)
    return pose_pixels(pose0, hw), pose_pixels(pose1, hw), rotation


def decode_pick(pick_logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick logits (B, H, W) -> the softmax over each map's pixels (B, H * W) float32 and its argmax pixel
    (B, 2) (row, col)."""
    b, h, w = pick_logits.shape
    pick_prob = F.softmax(pick_logits.reshape(b, h * w).float(), dim=1)
    pick_index = torch.argmax(pick_prob, dim=1)
    return pick_prob, torch.stack([pick_index // w, pick_index % w], dim=1)


def decode_place(place_logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Place logits (B, R, H, W) -> the argmax (B,) over each map's rotations x pixels (flat index
    ``(bin * H + row) * W + col``) and the softmax's maximum over rotations (B, H, W) float32."""
    b, n_rot, h, w = place_logits.shape
    place_prob = F.softmax(place_logits.reshape(b, n_rot * h * w).float(), dim=1)
    place_index = torch.argmax(place_prob, dim=1)
    return place_index, place_prob.reshape(b, n_rot, h, w).amax(dim=1)


def actions(
    pick_pix: torch.Tensor,
    pick_prob: torch.Tensor,
    place_index: torch.Tensor,
    place_heatmap: torch.Tensor,
    heights: list[np.ndarray],
    bin_yaw: Callable[[int], float],
) -> list[dict[str, Any]]:
    """The B actions of :func:`decode_pick` and :func:`decode_place`'s outputs over height maps (H, W) as
    ``PickPlaceAgent.act`` returns them; ``bin_yaw`` gives a rotation bin's yaw (the place head's)."""
    b, (h, w) = len(heights), heights[0].shape
    pick_pix_np = pick_pix.cpu().numpy()
    place_index_np = place_index.cpu().numpy()
    pick_heatmaps = pick_prob.reshape(b, h, w).cpu().numpy().astype(np.float32)
    place_heatmaps = place_heatmap.cpu().numpy().astype(np.float32)
    results = []
    for i in range(b):
        pick = (int(pick_pix_np[i, 0]), int(pick_pix_np[i, 1]))
        rot_bin, rest = divmod(int(place_index_np[i]), h * w)
        place = (rest // w, rest % w)
        place_yaw = bin_yaw(rot_bin)
        results.append(
            {
                "pose0": (pix_to_xyz(pick, heights[i]), yaw_to_quat(0.0)),
                "pose1": (pix_to_xyz(place, heights[i]), yaw_to_quat(place_yaw)),
                "pick_pix": pick,
                "place_pix": place,
                "place_rot": place_yaw % (2 * math.pi),
                "place_bin": rot_bin,
                "pick_heatmap": pick_heatmaps[i],
                "place_heatmap": place_heatmaps[i],
            }
        )
    return results


def act_input(observations: list[dict[str, np.ndarray]], device: torch.device) -> tuple[torch.Tensor, list[np.ndarray]]:
    """B observations of one image size (``color`` (H, W, 3) uint8, ``height`` (H, W)) -> the raw input (B, 6, H,
    W) on ``device`` and the height maps as float32 (the actions' z); ValueError for observations of mixed sizes."""
    heights = [np.asarray(obs["height"], dtype=np.float32) for obs in observations]
    if len({h.shape for h in heights}) != 1:
        raise ValueError(f"act_batch needs observations of one size, got {sorted({h.shape for h in heights})}")
    color = torch.from_numpy(np.stack([np.asarray(obs["color"]) for obs in observations]))
    return raw_input(color.to(device), torch.from_numpy(np.stack(heights)).to(device)), heights


def decide(
    x: torch.Tensor,
    heights: list[np.ndarray],
    sentence: torch.Tensor | None,
    pick_forward: PickForward,
    place_forward: PlaceForward,
    bin_yaw: Callable[[int], float],
) -> list[dict[str, Any]]:
    """The B actions of raw input ``x`` (B, 6, H, W): one batched pick forward, its argmax pixels, one batched
    place forward over the (observation, chosen pick) pairs, as :func:`actions` gives them."""
    pick_prob, pick_pix = decode_pick(pick_forward(x, sentence))
    place_index, place_heatmap = decode_place(place_forward(x, pick_pix, sentence))
    return actions(pick_pix, pick_prob, place_index, place_heatmap, heights, bin_yaw)
