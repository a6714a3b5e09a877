"""SE(2) augmentation of top-down observations, applied consistently to images and action pixels.

A transform is a rotation by ``theta`` about a pivot followed by a shift, in (x = column, y = row) image
coordinates, drawn as the reference CLIPort and Ravens draw it: ``theta`` from N(0, 60 degrees), the shift
from N(0, min(H, W) / 6) pixels per axis, redrawn until every action pixel stays inside the image. The
training recipes differ in the pivot and the interpolation (see :data:`PIVOTS`, :data:`INTERPOLATIONS`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

ANGLE_STD = math.radians(60)
SHIFT_STD = 26.7  # pixels: min(320, 160) / 6

#: ``half_size``: (W / 2, H / 2), the reference CLIPort's and Ravens' pivot; ``centre``: ((W - 1) / 2, (H - 1) / 2),
#: the image's geometric centre in pixel-centre coordinates (cliport 0.2's, kept by the legacy recipe).
PIVOTS = ("half_size", "centre")
#: ``linear``: the reference CLIPort's warp (bilinear, colours truncated to integers); ``nearest``: Ravens'.
INTERPOLATIONS = ("linear", "nearest")


def pivot_point(shape: tuple[int, int], pivot: str) -> tuple[float, float]:
    """The (x, y) pivot of an image of ``shape`` (rows, cols) by the name in :data:`PIVOTS`."""
    rows, cols = shape
    if pivot == "half_size":
        return cols / 2, rows / 2
    if pivot == "centre":
        return (cols - 1) / 2, (rows - 1) / 2
    raise ValueError(f"unknown augmentation pivot {pivot!r}; choose one of {', '.join(PIVOTS)}")


def image_transform(theta: float, shift: np.ndarray | tuple[float, float], pivot: tuple[float, float]) -> np.ndarray:
    """The 2x3 affine that rotates by ``theta`` (radians; +x towards +y) about ``pivot`` (x, y), then shifts by
    ``shift`` (x, y) pixels: ``T(pivot) @ [R(theta) | shift] @ T(-pivot)``, the reference's composition."""
    c, s = math.cos(theta), math.sin(theta)
    px, py = pivot
    rotate = np.array([[c, -s, shift[0]], [s, c, shift[1]], [0.0, 0.0, 1.0]])
    to_pivot = np.array([[1.0, 0.0, -px], [0.0, 1.0, -py], [0.0, 0.0, 1.0]])
    from_pivot = np.array([[1.0, 0.0, px], [0.0, 1.0, py], [0.0, 0.0, 1.0]])
    return (from_pivot @ rotate @ to_pivot)[:2]


def _lands_inside(m: np.ndarray, pix: tuple[int, int], shape: tuple[int, int]) -> bool:
    # As the reference: the transformed pixel, unrounded and rounded, must lie in [0, size) on both axes.
    x, y = m @ np.array([pix[1], pix[0], 1.0], dtype=np.float32).astype(np.float64)
    rounded = (round(y), round(x))
    return 0 <= y < shape[0] and 0 <= x < shape[1] and 0 <= rounded[0] < shape[0] and 0 <= rounded[1] < shape[1]


def sample_se2(
    rng: np.random.Generator,
    shape: tuple[int, int],
    pixels: list[tuple[int, int]],
    angle_std: float = ANGLE_STD,
    shift_std: float = SHIFT_STD,
    max_tries: int = 100,
    pivot: str = "half_size",
) -> np.ndarray:
    """A random 2x3 affine (:func:`image_transform`) about the named pivot, redrawn until every (row, col) pixel
    in ``pixels`` stays inside the image; the identity if none of ``max_tries`` draws fits (the reference
    draws forever)."""
    centre = pivot_point(shape, pivot)
    for _ in range(max_tries):
        theta = rng.normal(0.0, angle_std)
        shift = rng.normal(0.0, shift_std, size=2)
        m = image_transform(theta, shift, centre)
        if all(_lands_inside(m, px, shape) for px in pixels):
            return m
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def transform_pixel(m: np.ndarray, pix: tuple[int, int]) -> tuple[int, int]:
    """Where (row, col) pixel ``pix`` lands under affine ``m`` (rounded half to even, as numpy's round)."""
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


def warp(image: np.ndarray, m: np.ndarray, interpolation: str = "nearest") -> np.ndarray:
    """Apply affine ``m`` to an (H, W) or (H, W, C) image, zeros outside; ``interpolation`` from
    :data:`INTERPOLATIONS`."""
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"unknown interpolation {interpolation!r}; choose one of {', '.join(INTERPOLATIONS)}")
    rows, cols = image.shape[:2]
    flag = cv2.INTER_LINEAR if interpolation == "linear" else cv2.INTER_NEAREST
    return cv2.warpAffine(image, m, (cols, rows), flags=flag, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def warp_observation(
    color: np.ndarray, height: np.ndarray, m: np.ndarray, interpolation: str = "nearest"
) -> tuple[np.ndarray, np.ndarray]:
    """Colour (H, W, 3) uint8 and height (H, W) warped as the reference codes warp their (H, W, 6) float32 input
    (colour, height x 3) in one ``cv2.warpAffine`` call (OpenCV interpolates 6-channel images along another
    path than 1- to 4-channel ones, so splitting the channels would change the result). ``linear`` then
    truncates the colours to integers, as the reference CLIPort's ``perturb`` does. Returns colour (H, W, 3)
    uint8 and height (H, W) float32."""
    h = np.asarray(height, dtype=np.float32)[..., None]
    stacked = np.concatenate([np.asarray(color, dtype=np.float32), h, h, h], axis=2)
    out = warp(stacked, m, interpolation)
    colour = np.clip(out[..., :3].astype(np.int32), 0, 255).astype(np.uint8)
    return colour, np.ascontiguousarray(out[..., 3])
