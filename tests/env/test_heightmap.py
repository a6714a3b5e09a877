import numpy as np
import pytest

from cliport.env import heightmap as hm


def test_shape_and_roundtrip():
    assert hm.heightmap_shape() == (320, 160)
    rng = np.random.default_rng(0)
    for _ in range(200):
        u, v = int(rng.integers(0, 320)), int(rng.integers(0, 160))
        xyz = hm.pix_to_xyz((u, v), 0.01)
        assert hm.xyz_to_pix(xyz) == (u, v)
        assert xyz[2] == pytest.approx(0.01)


def test_projection_bins_by_floor_and_highest_wins():
    s = hm.PIXEL_SIZE
    points = np.array([[0.5, 0.0, 0.02], [0.5, 0.0, 0.05], [0.3 + s / 2, -0.4 + s / 2, 0.01], [0.9, 0.0, 0.01],
                       [0.25 + 10.9 * s, -0.5 + 20.9 * s, 0.03], [0.75, 0.0, 0.01]])  # fmt: skip
    colors = np.array([[10, 10, 10], [200, 0, 0], [0, 255, 0], [1, 2, 3], [7, 7, 7], [9, 9, 9]], dtype=np.uint8)
    height, color, seen = hm.project_to_heightmap(points, colors)
    u, v = hm.xyz_to_pix((0.5, 0.0))
    assert height[u, v] == pytest.approx(0.05)
    assert tuple(color[u, v]) == (200, 0, 0)
    assert height[32, 16] == pytest.approx(0.01) and seen[32, 16]  # (0.3, -0.4) is the corner of cell (32, 16)
    # 0.9 of a cell past a corner is still that cell (the reference floors; rounding would move it on).
    assert seen[20, 10] and tuple(color[20, 10]) == (7, 7, 7) and not seen[21, 11]
    assert seen.sum() == 3  # x = 0.9 is out of bounds, and so is x = 0.75 (the upper bound is open)


def test_fusion_max_height_mean_of_non_black_colours():
    shape = (320, 160)
    h1, h2 = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    h1[5, 5], h2[5, 5] = 0.02, 0.03
    c1, c2 = np.zeros(shape + (3,), np.uint8), np.zeros(shape + (3,), np.uint8)
    c1[5, 5], c2[5, 5] = (100, 0, 0), (201, 0, 0)
    c1[6, 6] = (50, 50, 50)
    c1[7, 7], c2[7, 7], h2[7, 7] = (90, 90, 90), (0, 0, 0), 0.01  # the second camera saw black there
    color, height = hm.fuse_heightmaps([h1, h2], [c1, c2])
    assert height[5, 5] == pytest.approx(0.03) and height[7, 7] == pytest.approx(0.01)
    assert tuple(color[5, 5]) == (150, 0, 0)  # 150.5 rounds half to even, as numpy does
    assert tuple(color[6, 6]) == (50, 50, 50)  # seen by one camera only: not averaged with black
    assert tuple(color[7, 7]) == (90, 90, 90)  # a black colour counts as no view of the cell


def test_pointcloud_backprojection():
    k = np.array([[450.0, 0, 320], [0, 450, 240], [0, 0, 1]])
    depth = np.full((480, 640), 2.0, np.float32)
    pts = hm.pointcloud_from_depth(depth, k)
    assert pts[240, 320] == pytest.approx([0.0, 0.0, 2.0])
    assert pts[240, 545] == pytest.approx([225 * 2.0 / 450, 0.0, 2.0])


def _down_camera(position=(0.5, 0.0, 1.0), zrange=(0.01, 10.0)):
    """A 60 x 80 camera looking straight down at (x, y) of its position."""
    from cliport.env.cameras import CameraConfig
    from cliport.env.transforms import euler_to_quat

    k = (100.0, 0.0, 40.0, 0.0, 100.0, 30.0, 0.0, 0.0, 1.0)
    return CameraConfig((60, 80), k, position, euler_to_quat(np.pi, 0.0, 0.0), zrange)


def test_fuse_cameras_sees_a_plane_and_counts_cells_per_camera():
    cam = _down_camera()
    depth = np.full((60, 80), 0.97, np.float32)  # a plane 3 cm above the table
    color = np.full((60, 80, 3), 200, np.uint8)
    depth[:, :40] = 0.0  # no reading: dropped, not a point at the camera
    depth[0, 79] = np.nan
    away = _down_camera(position=(3.0, 0.0, 1.0))  # sees only points outside the bounds
    fused = hm.fuse_cameras([(color, depth), (color, depth)], [cam, away])
    seen = fused.height > 0
    assert fused.cells_per_camera[0] > 0 and fused.cells_per_camera[1] == 0
    assert seen.sum() == fused.cells_per_camera[0]
    assert np.allclose(fused.height[seen], 0.03, atol=1e-5)
    assert np.all(fused.color[seen] == 200) and np.all(fused.color[~seen] == 0)
    # Half of the image had no reading: about half of the cells are missing.
    full = hm.fuse_cameras([(color, np.full((60, 80), 0.97, np.float32))], [cam])
    assert fused.cells_per_camera[0] < 0.6 * full.cells_per_camera[0]


def test_fuse_cameras_drops_depth_outside_zrange():
    depth = np.full((60, 80), 0.97, np.float32)
    color = np.zeros((60, 80, 3), np.uint8)
    fused = hm.fuse_cameras([(color, depth)], [_down_camera(zrange=(0.01, 0.9))])
    assert fused.cells_per_camera == (0,) and not fused.height.any()
