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


def warp(image: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Apply affine ``m`` to an (H, W) or (H, W, C) image; nearest neighbour, zeros outside."""
    rows, cols = image.shape[:2]
    return cv2.warpAffine(
        image, m, (cols, rows), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0
    )
