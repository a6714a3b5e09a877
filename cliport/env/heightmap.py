"""Top-down orthographic heightmaps fused from RGB-D cameras, and pixel <-> world conversions.

The rule is the reference CLIPort's (``get_fused_heightmap`` and the functions it calls), so that the
same camera images give the same maps, bit for bit, as the ones its published checkpoints were trained
on. A heightmap has shape (rows, cols) = (320, 160) for the default bounds; row ``u`` runs along world y
and column ``v`` along world x.

- Binning: cell (u, v) holds the points with ``x`` in ``[x0 + v * s, x0 + (v + 1) * s)`` and ``y`` in
  ``[y0 + u * s, y0 + (u + 1) * s)`` (floor), and z in ``[z0, z1)``.
- Winner: the highest point of a cell gives its height (metres above ``z0``) and colour; points are
  ordered by world z with numpy's default ``argsort`` and written in that order, so among points of equal
  z the one the sort puts last wins, as in the reference.
- Fusion: height is the maximum over the cameras (0 where none saw the cell); colour is the mean over
  the cameras whose colour of the cell is not black (0, 0, 0), rounded half to even; black where none.
- Arithmetic: back-projection and the camera-to-world transform are computed in float64 and rounded to
  float32 once, as the reference computes them with NumPy 2, so boundary points fall in the same cells.

``pix_to_xyz`` returns the lower corner ``(x0 + v * s, y0 + u * s)`` of a cell and ``xyz_to_pix``
rounds to the nearest corner: the reference's conversions, which its agents' actions and training labels
use, so the half-cell offset between binning and labelling is the reference's too.
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
    """Back-project a (H, W) depth image with 3x3 intrinsics into (H, W, 3) float32 camera-frame points.

    ``x = (col - cx) * (depth / fx)``, ``y = (row - cy) * (depth / fy)``, ``z = depth``, in float64 and
    rounded to float32 once.
    """
    k = np.asarray(intrinsics, dtype=np.float64)
    d = np.asarray(depth)
    d64 = d.astype(np.float64)
    h, w = d.shape
    points = np.empty((h, w, 3), dtype=np.float32)
    points[..., 0] = (np.arange(w, dtype=np.float64)[None, :] - k[0, 2]) * (d64 / k[0, 0])
    points[..., 1] = (np.arange(h, dtype=np.float64)[:, None] - k[1, 2]) * (d64 / k[1, 1])
    points[..., 2] = d
    return points


def transform_points(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Apply x -> R x + t to an (..., 3) array of points; float32 out, computed in float64.

    Each coordinate is ``((R[i, 0] x + R[i, 1] y) + R[i, 2] z) + t[i]`` in that order (the reference's
    homogeneous 4x4 product summed left to right).
    """
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64).reshape(3)
    p = np.asarray(points)
    x, y, z = (p[..., i].astype(np.float64) for i in range(3))
    out = np.empty(p.shape, dtype=np.float32)
    for i in range(3):
        acc = x * r[i, 0]
        acc += y * r[i, 1]
        acc += z * r[i, 2]
        acc += t[i]
        out[..., i] = acc
    return out


def project_to_heightmap(
    points: np.ndarray,
    colors: np.ndarray,
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographically project world points onto the xy grid; the highest point wins each cell.

    Binning and winner as described in the module docstring (the reference's ``get_heightmap``).

    Args:
        points: (N, 3) or (H, W, 3) world-frame points (float32 as :func:`transform_points` gives them;
            their z values are what is sorted).
        colors: matching per-point values, (N, C) or (H, W, C) (uint8 colours, or e.g. int32
            segmentation ids with C = 1), or (H, W) for one channel.
    Returns:
        height (rows, cols) float32 above ``z0`` (0 where unseen), color (rows, cols, C) of the
        values' dtype (0 where unseen), seen (rows, cols) bool: whether any point fell in the cell.
    """
    rows, cols = heightmap_shape(bounds, pixel_size)
    pts = np.asarray(points).reshape(-1, 3)
    channels = 1 if colors.ndim == points.ndim - 1 else colors.shape[-1]
    col = np.asarray(colors).reshape(-1, channels)
    b = np.asarray(bounds, dtype=np.float64)
    # Comparisons with float64 bounds are exact whatever the points' dtype.
    keep = (pts[:, 0] >= b[0, 0]) & (pts[:, 0] < b[0, 1])
    keep &= (pts[:, 1] >= b[1, 0]) & (pts[:, 1] < b[1, 1])
    keep &= (pts[:, 2] >= b[2, 0]) & (pts[:, 2] < b[2, 1])
    index = np.flatnonzero(keep)
    index = index[np.argsort(pts[index, 2])]  # the reference sorts the kept points' own z values
    kept = pts[index].astype(np.float64)
    v = np.clip(np.floor((kept[:, 0] - b[0, 0]) / pixel_size).astype(np.int64), 0, cols - 1)
    u = np.clip(np.floor((kept[:, 1] - b[1, 0]) / pixel_size).astype(np.int64), 0, rows - 1)
    cell = u * cols + v
    height = np.zeros(rows * cols, dtype=np.float32)
    color = np.zeros((rows * cols, channels), dtype=colors.dtype)
    seen = np.zeros(rows * cols, dtype=bool)
    # Fancy assignment writes in order, so the last (highest) point of a cell stays.
    height[cell] = kept[:, 2] - b[2, 0]
    color[cell] = col[index]
    seen[cell] = True
    return height.reshape(rows, cols), color.reshape(rows, cols, channels), seen.reshape(rows, cols)


def fuse_heightmaps(heights: list[np.ndarray], colors: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Fuse per-camera maps: height = max over cameras, colour = mean over the cameras whose colour of
    the cell is not black (black where none), rounded half to even.

    Returns (color (rows, cols, 3) uint8, height (rows, cols) float32).
    """
    stacked = np.stack(colors).astype(np.float32)
    count = np.sum(np.sum(stacked, axis=3) > 0, axis=0)
    count[count == 0] = 1
    color = np.round(np.sum(stacked, axis=0) / count[..., None]).astype(np.uint8)
    height = np.max(np.stack(heights), axis=0).astype(np.float32)
    return color, height


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

    color: (rows, cols, 3) uint8 (0 where no camera saw the cell, or saw it black); height: (rows, cols) float32 metres
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
    projected onto the grid (the highest point wins a cell) and the cameras are fused (height = max,
    colour = mean over the cameras whose colour of the cell is not black): the reference CLIPort's rule,
    see the module docstring. Depth values that are not finite or outside the camera's ``zrange`` (e.g.
    0 = no reading on a real sensor) are dropped; a simulator's depth is always inside it, so this
    changes nothing for rendered images.

    Args:
        images: per camera (color (H, W, 3) uint8, depth (H, W) float metres along the optical axis).
        cameras: per camera its model (intrinsics for (H, W), pose, zrange).
        bounds: (3, 2) workspace bounds [[x0, x1], [y0, y1], [z0, z1]] in metres.
        pixel_size: metres per heightmap cell.
    """
    if len(images) != len(cameras):
        raise ValueError(f"{len(images)} images for {len(cameras)} cameras")
    heights, colors, seen_cells = [], [], []
    for (color, depth), cam in zip(images, cameras, strict=True):
        near, far = cam.zrange
        depth = np.asarray(depth)
        valid = np.isfinite(depth) & (depth >= near) & (depth <= far)
        points = pointcloud_from_depth(np.where(valid, depth, 0), cam.K)
        points = transform_points(points, quat_to_matrix(cam.rotation), np.asarray(cam.position, dtype=np.float64))
        h, c, s = project_to_heightmap(points[valid], np.asarray(color)[valid], bounds, pixel_size)
        heights.append(h)
        colors.append(c)
        seen_cells.append(int(s.sum()))
    fused_color, fused_height = fuse_heightmaps(heights, colors)
    return FusedMap(fused_color, fused_height, tuple(seen_cells))


def pix_to_xyz(
    pix: tuple[int, int],
    height: np.ndarray | float,
    bounds: np.ndarray = BOUNDS,
    pixel_size: float = PIXEL_SIZE,
) -> tuple[float, float, float]:
    """World (x, y, z) of heightmap pixel (u, v): the cell's lower corner ``(x0 + v * s, y0 + u * s)`` at
    ``z0`` plus the height there; ``height`` is the heightmap or the height itself (the reference's rule)."""
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
    """Heightmap pixel (u, v) of world position (x, y[, z]): rounded to the nearest cell corner, so that
    ``xyz_to_pix(pix_to_xyz(pix, h)) == pix`` (the reference's rule; binning points floors instead)."""
    u = int(np.round((position[1] - bounds[1, 0]) / pixel_size))
    v = int(np.round((position[0] - bounds[0, 0]) / pixel_size))
    return u, v
