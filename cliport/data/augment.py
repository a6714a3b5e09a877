"""SE(2) augmentation of top-down observations, applied consistently to images and action pixels."""

from __future__ import annotations

import math

import cv2
import numpy as np

ANGLE_STD = math.radians(60)
SHIFT_STD = 26.7  # pixels


def sample_se2(
    rng: np.random.Generator,
    shape: tuple[int, int],
    pixels: list[tuple[int, int]],
    angle_std: float = ANGLE_STD,
    shift_std: float = SHIFT_STD,
    max_tries: int = 100,
) -> np.ndarray:
    """A 2x3 affine (rotation about the image centre, then a shift) in (x=col, y=row) coordinates,
    resampled until every (row, col) pixel in ``pixels`` stays inside the image; identity if none fits."""
    rows, cols = shape
    centre = ((cols - 1) / 2.0, (rows - 1) / 2.0)
    for _ in range(max_tries):
        angle = rng.normal(0.0, angle_std)
        shift = rng.normal(0.0, shift_std, size=2)
        m = cv2.getRotationMatrix2D(centre, math.degrees(angle), 1.0)
        m[:, 2] += shift
        if all(_inside(transform_pixel(m, px), shape) for px in pixels):
            return m
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _inside(pix: tuple[int, int], shape: tuple[int, int]) -> bool:
    return 0 <= pix[0] < shape[0] and 0 <= pix[1] < shape[1]


def transform_pixel(m: np.ndarray, pix: tuple[int, int]) -> tuple[int, int]:
    """Where (row, col) pixel ``pix`` lands under affine ``m`` (rounded)."""
    x, y = m @ np.array([pix[1], pix[0], 1.0])
    return int(round(y)), int(round(x))


def transform_pose(m: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """A world pose (7,) = xyz + quaternion xyzw moved as its heightmap pixel moves under affine ``m``.

    The position is snapped to its pixel's centre and carried to where that pixel lands (unrounded, so
    that ``xyz_to_pix`` of the result equals :func:`transform_pixel` of the pixel); the yaw turns by
    the affine's rotation (image columns and rows run along world x and y); z and tilt are kept.
    """
    from cliport.env import heightmap as hm
    from cliport.env.transforms import multiply, yaw_to_quat

    u, v = hm.xyz_to_pix(pose[:3])
    x, y = m @ np.array([v, u, 1.0])
    out = np.array(pose, dtype=np.float64)
    out[0] = hm.BOUNDS[0, 0] + x * hm.PIXEL_SIZE
    out[1] = hm.BOUNDS[1, 0] + y * hm.PIXEL_SIZE
    turn = math.atan2(m[1, 0], m[0, 0])
    out[3:] = multiply(((0.0, 0.0, 0.0), yaw_to_quat(turn)), ((0.0, 0.0, 0.0), tuple(out[3:])))[1]
    return out


def warp(image: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Apply affine ``m`` to an (H, W) or (H, W, C) image; nearest neighbour, zeros outside."""
    rows, cols = image.shape[:2]
    return cv2.warpAffine(
        image, m, (cols, rows), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
