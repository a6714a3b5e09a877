import math

import torch

from cliport.models import rotation


def test_cropped_rotation_is_the_whole_image_warp_cropped() -> None:
    """rotated_crops samples only the crop, with exactly the grid of the whole-image warp."""
    torch.manual_seed(0)
    x = torch.rand(2, 3, 48, 40)
    pivots = torch.tensor([[20, 15], [30, 22]])
    crops = rotation.rotated_crops(x, pivots, n_rotations=6, crop_size=16).reshape(2, 6, 3, 16, 16)
    for b in range(2):
        r, c = pivots[b].tolist()
        for k in range(6):
            whole = rotation.warp(x[b : b + 1], k * 60.0, (r, c))
            assert torch.equal(crops[b, k], whole[0, :, r - 8 : r + 8, c - 8 : c + 8])


def test_rotation_by_zero_resamples_by_float_rounding_only() -> None:
    x = torch.rand(1, 2, 32, 32)
    theta = rotation.sampling_theta((0.0,), torch.tensor([[16, 16]]), (32, 32))
    assert torch.equal(theta[0, 0], torch.eye(2, 3))
    torch.testing.assert_close(rotation.warp(x, 0.0, (16, 16)), x, rtol=0, atol=1e-5)


def test_a_square_turns_counter_clockwise_on_screen_with_kornias_scale_quirk() -> None:
    """A bright pixel right of the pivot goes above it after +90 degrees (rows run downwards), off the exact
    rotation by kornia's (size - 1) / size scaling of offsets about the pivot."""
    size, pivot = 65, (32, 32)
    x = torch.zeros(1, 1, size, size)
    x[0, 0, 32, 52] = 1.0  # 20 px right of the pivot
    out = rotation.warp(x, 90.0, pivot)[0, 0]
    row, col = divmod(int(out.argmax()), size)
    assert col == 32 and row == 12
    # The exact rotation would put the pixel at row 12.0; kornia samples it from 20 * 64 / 65 px off the
    # pivot in the other axis, so its mass spreads over two rows.
    theta = rotation.sampling_theta((90.0,), torch.tensor([pivot]), (size, size))[0, 0]
    assert math.isclose(float(theta[0, 1]), -1.0, abs_tol=1e-6) and math.isclose(float(theta[1, 0]), 1.0, abs_tol=1e-6)
    assert 0.5 < float(out.max()) < 1.0


def test_geometry_stays_float32_under_bfloat16_autocast() -> None:
    """Training on a GPU runs under bf16 autocast: the sampling grids must still be float32 (bf16 has no
    matrix inverse, and its 8-bit mantissa would move a 320-pixel grid's positions by pixels)."""
    torch.manual_seed(0)
    x = torch.rand(2, 3, 48, 40)
    pivots = torch.tensor([[20, 15], [30, 22]])
    plain = rotation.rotated_crops(x, pivots, 6, 16), rotation.warp(x, 30.0, (20, 15))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        autocast = rotation.rotated_crops(x, pivots, 6, 16), rotation.warp(x, 30.0, (20, 15))
    for got, want in zip(autocast, plain, strict=True):
        assert torch.equal(got, want)


def test_a_warmed_up_forward_copies_no_host_data(monkeypatch) -> None:
    """CUDA graph capture refuses host-to-device copies: after a first call, the rotations build no tensor
    from Python data (their constants are cached per angle set, image size and device)."""
    x = torch.rand(2, 3, 48, 40)
    pivots = torch.tensor([[20, 15], [30, 22]])

    def calls() -> None:
        rotation.rotated_crops(x, pivots, 6, 16)
        rotation.warp(x, 0.0, (24, 20))

    calls()

    def refuse(*args, **kwargs):
        raise AssertionError("a tensor was built from host data inside a warmed-up forward")

    monkeypatch.setattr(torch, "tensor", refuse)
    calls()
