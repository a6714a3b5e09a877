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


def test_projection_bins_on_pixel_centres_and_highest_wins():
    points = np.array([[0.5, 0.0, 0.02], [0.5, 0.0, 0.05], [0.3, -0.4, 0.01], [0.9, 0.0, 0.01]])
    colors = np.array([[10, 10, 10], [200, 0, 0], [0, 255, 0], [1, 2, 3]], dtype=np.uint8)
    height, color, seen = hm.project_to_heightmap(points, colors)
    u, v = hm.xyz_to_pix((0.5, 0.0))
    assert height[u, v] == pytest.approx(0.05)
    assert tuple(color[u, v]) == (200, 0, 0)
    u2, v2 = hm.xyz_to_pix((0.3, -0.4))
    assert height[u2, v2] == pytest.approx(0.01) and seen[u2, v2]
    assert seen.sum() == 2  # the point at x=0.9 is out of bounds


def test_fusion_max_height_mean_colour():
    shape = (320, 160)
    h1, h2 = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    h1[5, 5], h2[5, 5] = 0.02, 0.03
    c1, c2 = np.zeros(shape + (3,), np.uint8), np.zeros(shape + (3,), np.uint8)
    c1[5, 5], c2[5, 5] = (100, 0, 0), (200, 0, 0)
    c1[6, 6] = (50, 50, 50)
    s1, s2 = np.zeros(shape, bool), np.zeros(shape, bool)
    s1[5, 5] = s2[5, 5] = s1[6, 6] = True
    color, height = hm.fuse_heightmaps([h1, h2], [c1, c2], [s1, s2])
    assert height[5, 5] == pytest.approx(0.03)
    assert tuple(color[5, 5]) == (150, 0, 0)
    assert tuple(color[6, 6]) == (50, 50, 50)  # seen by one camera only: not averaged with black


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
