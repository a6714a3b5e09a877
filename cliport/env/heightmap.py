"""Top-down orthographic heightmaps fused from RGB-D cameras, and pixel <-> world conversions.

Conventions: a heightmap has shape (rows, cols) = (320, 160) for the default bounds; row ``u`` runs
along world y and column ``v`` along world x. Cell (u, v) is centred on
``(x0 + v * s, y0 + u * s)``, the point ``pix_to_xyz`` returns, so that binning points, labelling
actions (``xyz_to_pix``) and executing them (``pix_to_xyz``) all agree to the pixel.
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
    """Back-project a (H, W) depth image with 3x3 intrinsics into (H, W, 3) camera-frame points."""
    h, w = depth.shape
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    px = np.arange(w, dtype=np.float32)[None, :]
    py = np.arange(h, dtype=np.float32)[:, None]
    x = (px - cx) * depth / fx
    y = (py - cy) * depth / fy
    return np.stack([x, np.broadcast_to(y, depth.shape) * 1.0, depth], axis=-1).astype(np.float32)


def transform_points(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Apply x -> R x + t to an (..., 3) array of points."""
    return points @ rotation.T.astype(np.float32) + translation.astype(np.float32)


def project_to_heightmap(
    points: np.ndarray,
    colors: np.ndarray,
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographically project world points onto the xy grid; the highest point wins each cell.

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
    v = np.round((pts[:, 0] - bounds[0, 0]) / pixel_size).astype(np.int64)
    u = np.round((pts[:, 1] - bounds[1, 0]) / pixel_size).astype(np.int64)
    z = pts[:, 2] - bounds[2, 0]
    keep = (v >= 0) & (v < cols) & (u >= 0) & (u < rows) & (z >= 0) & (z < bounds[2, 1] - bounds[2, 0])
    cell = u[keep] * cols + v[keep]
    z = z[keep]
    col = col[keep]
    order = np.lexsort((z, cell))
    cell, z, col = cell[order], z[order], col[order]
    last = np.ones(cell.shape, dtype=bool)
    last[:-1] = cell[1:] != cell[:-1]
    height = np.zeros(rows * cols, dtype=np.float32)
    color = np.zeros((rows * cols, channels), dtype=colors.dtype)
    seen = np.zeros(rows * cols, dtype=bool)
    height[cell[last]] = z[last]
    color[cell[last]] = col[last]
    seen[cell[last]] = True
    return height.reshape(rows, cols), color.reshape(rows, cols, channels), seen.reshape(rows, cols)


def fuse_heightmaps(
    heights: list[np.ndarray], colors: list[np.ndarray], seens: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse per-camera heightmaps: height = max over cameras, colour = mean over cameras that see the cell.

    Returns (color (rows, cols, 3) uint8, height (rows, cols) float32).
    """
    height = np.max(np.stack(heights), axis=0)
    seen = np.stack(seens).astype(np.float32)[..., None]
    total = np.sum(np.stack(colors).astype(np.float32) * seen, axis=0)
    count = np.maximum(np.sum(seen, axis=0), 1.0)
    color = np.round(total / count).astype(np.uint8)
    return color, height.astype(np.float32)


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
    projected onto the grid (highest point wins a cell) and the cameras are fused (height = max, colour
    = mean over the cameras that see the cell). Depth values that are not finite or outside the camera's
    ``zrange`` (e.g. 0 = no reading on a real sensor) are dropped.

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
    fused_color, fused_height = fuse_heightmaps(heights, colors, seens)
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
