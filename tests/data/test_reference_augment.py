"""The SE(2) augmentation against the reference CLIPort's ``utils.perturb`` (run from CLIPORT_REFERENCE_DIR in a
subprocess; skipped without it): given the reference's own draws of angle and shift, and its pivot, our
``cliport`` recipe's warp gives its image exactly and our pixel transform its labels."""

from __future__ import annotations

import numpy as np

from cliport.data import augment

SEEDS = np.arange(12)


def test_linear_augmentation_equals_the_reference_perturb(reference_utils, tmp_path) -> None:
    rng = np.random.default_rng(0)
    color = rng.integers(0, 256, (320, 160, 3)).astype(np.uint8)
    color[100:140, 40:90] = (200, 30, 30)  # flat patches, as a table and blocks make
    height = np.zeros((320, 160), np.float32)
    height[100:140, 40:90] = 0.04
    height += rng.random((320, 160), dtype=np.float32) * 1e-3
    pixels = np.array([[120, 60], [250, 120]])
    img = np.concatenate([color.astype(np.float32), np.repeat(height[..., None], 3, axis=2)], axis=2)
    ref = reference_utils(tmp_path, "perturb", img=img, pixels=pixels, seeds=SEEDS)

    for k in range(len(SEEDS)):
        pivot = augment.pivot_point(height.shape, "half_size")
        assert tuple(ref["pivot"][k]) == pivot
        m = augment.image_transform(float(ref["theta"][k]), ref["trans"][k], pivot)
        ours_color, ours_height = augment.warp_observation(color, height, m, "linear")
        np.testing.assert_array_equal(ours_color, ref["image"][k][..., :3])
        for c in range(3, 6):
            np.testing.assert_array_equal(ours_height, ref["image"][k][..., c].astype(np.float32))
        for (row, col), label in zip(pixels, ref["rounded"][k], strict=True):
            assert augment.transform_pixel(m, (int(row), int(col))) == tuple(int(v) for v in label)


def test_ravens_augmentation_keeps_every_value(tmp_path) -> None:
    # Nearest neighbour moves pixels without blending: every output value is an input value (or 0 outside).
    rng = np.random.default_rng(1)
    color = rng.integers(1, 256, (320, 160, 3)).astype(np.uint8)
    height = rng.random((320, 160), dtype=np.float32) + 0.5
    m = augment.image_transform(0.4, (7.5, -3.0), augment.pivot_point((320, 160), "half_size"))
    out_color, out_height = augment.warp_observation(color, height, m, "nearest")
    assert set(np.unique(out_height)) <= set(np.unique(height)) | {0.0}
    inside = out_height > 0
    assert inside.mean() > 0.5 and (out_color[inside] > 0).all()
