"""Top-down orthographic heightmaps fused from RGB-D cameras, and pixel <-> world conversions.

Conventions, the reference CLIPort's (``utils.get_heightmap``, ``get_fused_heightmap``,
``pix_to_xyz``, ``xyz_to_pix``), so that its checkpoints see the maps they were trained on: a heightmap
has shape (rows, cols) = (320, 160) for the default bounds; row ``u`` runs along world y and column
``v`` along world x. Cell (u, v) holds the points with x in [x0 + v s, x0 + (v + 1) s) and y in
[y0 + u s, y0 + (u + 1) s) (floor binning); ``pix_to_xyz`` returns its corner (x0 + v s, y0 + u s)
and ``xyz_to_pix`` rounds, so an action labelled from a position and executed at its pixel lands
within half a cell (1.6 mm) of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np

from cliport.env.transforms import quat_to_matrix

# Workspace bounds [[x0, x1], [y0, y1], [z0, z1]] in metres and the heightmap pixel size.
BOUNDS = np.array([[0.25, 0.75], [-0.5, 0.5], [0.0, 0.28]])
PIXEL_SIZE = 0.003125


def heightmap_shape(bounds: np.ndarray = BOUNDS, pixel_size: float = PIXEL_SIZE) -> tuple[int, int]:
    """(rows, cols) of the heightmap covering ``bounds``: rows along y, columns along x."""
    rows = int(round((bounds[1, 1] - bounds[1, 0]) / pixel_size))
    cols = int(round((bounds[0, 1] - bounds[0, 0]) / pixel_size))
    return rows, cols


def pointcloud_from_depth(depth: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Back-project a (H, W) depth image with 3x3 intrinsics into (H, W, 3) camera-frame points, float32
    (computed in float64 from the float64 intrinsics, as the reference does)."""
    h, w = depth.shape
    px, py = np.meshgrid(np.linspace(0, w - 1, w), np.linspace(0, h - 1, h))
    x = (px - intrinsics[0, 2]) * (depth / intrinsics[0, 0])
    y = (py - intrinsics[1, 2]) * (depth / intrinsics[1, 1])
    return np.float32([x, y, depth]).transpose(1, 2, 0)


def transform_points(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Apply x -> R x + t to an (..., 3) float32 array of points; each coordinate is the float64 sum of the
    homogeneous products, stored as float32 (the reference's arithmetic)."""
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    homogeneous = np.concatenate([points, np.ones((*points.shape[:-1], 1), dtype=points.dtype)], axis=-1)
    out = np.empty_like(points)
    for i in range(3):
        out[..., i] = np.sum(transform[i, :] * homogeneous, axis=-1)
    return out


def project_to_heightmap(
    points: np.ndarray,
    colors: np.ndarray,
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographically project world points onto the xy grid; the highest point wins each cell.

    Points with x in [x0, x1), y in [y0, y1) and z in [z0, z1) fall in the cell ``floor((x - x0) / s)``,
    ``floor((y - y0) / s)``; among a cell's points the last of a sort by z (numpy's default argsort)
    sets its height and value.

    Args:
        points: (N, 3) or (H, W, 3) world-frame points.
        colors: matching per-point values, (N, C) or (H, W, C) (uint8 colours, or e.g. int32
            segmentation ids with C = 1), or (H, W) for one channel.
    Returns:
        height (rows, cols) float32 above ``z0`` (0 where unseen), color (rows, cols, C) of the
        values' dtype (0 where unseen), seen (rows, cols) bool: whether any point fell in the cell.
    """
    rows, cols = heightmap_shape(bounds, pixel_size)
    pts = points.reshape(-1, 3)
    channels = 1 if colors.ndim == points.ndim - 1 else colors.shape[-1]
    col = colors.reshape(-1, channels)
    keep = (
        (pts[:, 0] >= bounds[0, 0]) & (pts[:, 0] < bounds[0, 1])
        & (pts[:, 1] >= bounds[1, 0]) & (pts[:, 1] < bounds[1, 1])
        & (pts[:, 2] >= bounds[2, 0]) & (pts[:, 2] < bounds[2, 1])
    )  # fmt: skip
    pts, col = pts[keep], col[keep]
    order = np.argsort(pts[:, -1])
    pts, col = pts[order], col[order]
    v = np.clip(np.int32(np.floor((pts[:, 0] - bounds[0, 0]) / pixel_size)), 0, cols - 1)
    u = np.clip(np.int32(np.floor((pts[:, 1] - bounds[1, 0]) / pixel_size)), 0, rows - 1)
    height = np.zeros((rows, cols), dtype=np.float32)
    color = np.zeros((rows, cols, channels), dtype=colors.dtype)
    seen = np.zeros((rows, cols), dtype=bool)
    height[u, v] = pts[:, 2] - bounds[2, 0]  # with repeated cells the last (highest) point is written
    color[u, v] = col
    seen[u, v] = True
    return height, color, seen


def fuse_heightmaps(heights: list[np.ndarray], colors: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Fuse per-camera maps as the reference does: height = max over cameras; colour = the mean over the
    cameras whose colour of the cell is not black (0, 0, 0), rounded; black where none.

    Returns (color (rows, cols, 3) uint8, height (rows, cols) float32).
    """
    colormaps = np.float32(colors)
    valid = np.sum(colormaps, axis=3) > 0
    repeat = np.sum(valid, axis=0)
    repeat[repeat == 0] = 1
    color = np.uint8(np.round(np.sum(colormaps, axis=0) / repeat[..., None]))
    return color, np.max(np.float32(heights), axis=0)


class CameraModel(Protocol):
    """What fusion needs of a camera (``cliport.env.cameras.CameraConfig`` is one)."""

    @property
    def K(self) -> np.ndarray: ...  # noqa: N802 - (3, 3) intrinsics

    @property
    def position(self) -> Sequence[float]: ...  # (3,) camera centre in the world (robot base) frame

    @property
    def rotation(self) -> Sequence[float]: ...  # (4,) camera-to-world quaternion xyzw, z forward, y down

    @property
    def zrange(self) -> Sequence[float]: ...  # (near, far) metres: depth outside is no measurement


class FusedMap(NamedTuple):
    """A top-down map fused from several cameras.

    color: (rows, cols, 3) uint8 (0 where no camera saw the cell); height: (rows, cols) float32 metres
    above ``z0`` (0 where unseen); cells_per_camera: how many cells each camera saw (0: nothing of the
    workspace, e.g. a wrong pose or depth unit).
    """

    color: np.ndarray
    height: np.ndarray
    cells_per_camera: tuple[int, ...]


def fuse_cameras(
    images: Sequence[tuple[np.ndarray, np.ndarray]],
    cameras: Sequence[CameraModel],
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> FusedMap:
    """Fuse RGB-D views into the top-down colour and height maps: the one fusion of the project.

    Each camera's depth is back-projected with its intrinsics, moved to the world frame by its pose,
    projected onto the grid (:func:`project_to_heightmap`: floor binning, the highest point wins a cell)
    and the cameras are fused (:func:`fuse_heightmaps`: height = max, colour = mean over the cameras
    whose colour of the cell is not black), all as the reference CLIPort computes them. Depth values that
    are not finite or outside the camera's ``zrange`` (e.g. 0 = no reading on a real sensor) are dropped.

    Args:
        images: per camera (color (H, W, 3) uint8, depth (H, W) float metres along the optical axis).
        cameras: per camera its model (intrinsics for (H, W), pose, zrange).
        bounds: (3, 2) workspace bounds [[x0, x1], [y0, y1], [z0, z1]] in metres.
        pixel_size: metres per heightmap cell.
    """
    if len(images) != len(cameras):
        raise ValueError(f"{len(images)} images for {len(cameras)} cameras")
    heights, colors, seens = [], [], []
    for (color, depth), cam in zip(images, cameras, strict=True):
        near, far = cam.zrange
        valid = np.isfinite(depth) & (depth >= near) & (depth <= far)
        points = pointcloud_from_depth(np.where(valid, depth, 0.0).astype(np.float32), cam.K)
        points = transform_points(points, quat_to_matrix(cam.rotation), np.asarray(cam.position, dtype=np.float64))
        h, c, s = project_to_heightmap(points[valid], color[valid], bounds, pixel_size)
        heights.append(h)
        colors.append(c)
        seens.append(s)
    fused_color, fused_height = fuse_heightmaps(heights, colors)
    return FusedMap(fused_color, fused_height, tuple(int(s.sum()) for s in seens))


def pix_to_xyz(
    pix: tuple[int, int],
    height: np.ndarray | float,
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> tuple[float, float, float]:
    """World (x, y, z) of heightmap pixel (u, v); ``height`` is the heightmap or the height there."""
    u, v = int(pix[0]), int(pix[1])
    h = float(height[u, v]) if isinstance(height, np.ndarray) else float(height)
    return (
        float(bounds[0, 0] + v * pixel_size),
        float(bounds[1, 0] + u * pixel_size),
        float(bounds[2, 0] + h),
    )


def xyz_to_pix(
    position: tuple[float, ...] | np.ndarray, bounds: np.ndarray = BOUNDS, pixel_size: float = PIXEL_SIZE
) -> tuple[int, int]:
    """Heightmap pixel (u, v) of world position (x, y[, z]) (rounded to the nearest cell)."""
    u = int(np.round((position[1] - bounds[1, 0]) / pixel_size))
    v = int(np.round((position[0] - bounds[0, 0]) / pixel_size))
    return u, v
