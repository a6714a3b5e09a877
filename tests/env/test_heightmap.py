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
    """Cell (u, v) holds x in [x0 + v s, x0 + (v + 1) s) (the reference's floor), its highest point gives
    height and colour; pix_to_xyz gives the cell's lower corner, which xyz_to_pix rounds back."""
    s = hm.PIXEL_SIZE
    x, y, _ = hm.pix_to_xyz((120, 80), 0.0)
    points = np.array(
        [
            [x + 0.7 * s, y + 0.7 * s, 0.02],
            [x + 0.2 * s, y + 0.9 * s, 0.05],  # same cell, higher: wins
            [x - 0.1 * s, y + 0.5 * s, 0.04],  # just below x: the previous column
            [0.9, 0.0, 0.01],  # out of bounds
            [x + 0.5 * s, y + 0.5 * s, 0.28],  # at the upper z bound: out
        ]
    )
    colors = np.array([[10, 10, 10], [200, 0, 0], [0, 255, 0], [1, 2, 3], [4, 5, 6]], dtype=np.uint8)
    height, color, seen = hm.project_to_heightmap(points, colors)
    assert height[120, 80] == pytest.approx(0.05) and tuple(color[120, 80]) == (200, 0, 0)
    assert height[120, 79] == pytest.approx(0.04) and tuple(color[120, 79]) == (0, 255, 0)
    assert seen.sum() == 2
    # Labelling rounds: a point 0.7 cells past the corner is labelled with the next cell.
    assert hm.xyz_to_pix((x + 0.7 * s, y + 0.7 * s)) == (121, 81)
    assert hm.xyz_to_pix((x, y)) == (120, 80)


def test_fusion_max_height_mean_of_non_black_colours():
    shape = (320, 160)
    h1, h2 = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    h1[5, 5], h2[5, 5] = 0.02, 0.03
    c1, c2 = np.zeros(shape + (3,), np.uint8), np.zeros(shape + (3,), np.uint8)
    c1[5, 5], c2[5, 5] = (100, 0, 0), (201, 0, 0)
    c1[6, 6] = (50, 50, 50)
    h1[7, 7], h2[7, 7] = 0.04, 0.01
    c1[7, 7], c2[7, 7] = (0, 0, 0), (90, 30, 10)  # seen black by camera 1
    color, height = hm.fuse_heightmaps([h1, h2], [c1, c2])
    assert height[5, 5] == pytest.approx(0.03) and height[7, 7] == pytest.approx(0.04)
    assert tuple(color[5, 5]) == (150, 0, 0)  # 150.5 rounds half to even
    assert tuple(color[6, 6]) == (50, 50, 50)  # seen by one camera only: not averaged with black
    assert tuple(color[7, 7]) == (90, 30, 10)  # a black colour does not count either
    assert not color[8, 8].any() and height[8, 8] == 0


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
