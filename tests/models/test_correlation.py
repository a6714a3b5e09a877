import torch
import torch.nn.functional as F

from cliport.models.correlation import direct_cross_correlation, fft_cross_correlation, transport_correlation


def _inputs(b: int, r: int, c: int, hw: tuple[int, int], k: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    key = torch.randn(b, c, *hw, generator=gen, dtype=torch.float64)
    kernels = torch.randn(b, r, c, k, k, generator=gen, dtype=torch.float64)
    return key.float().requires_grad_(), kernels.float().requires_grad_()


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max().detach() / b.abs().max().detach())


def test_fft_correlation_matches_conv2d_forward_and_backward() -> None:
    key, kernels = _inputs(b=2, r=5, c=3, hw=(40, 24), k=16)
    fft = fft_cross_correlation(key, kernels)
    direct = direct_cross_correlation(key, kernels)
    assert fft.shape == direct.shape == (2, 5, 25, 9)
    assert _rel(fft, direct) < 1e-4

    weight = torch.randn_like(direct)
    g_key_fft, g_ker_fft = torch.autograd.grad((fft * weight).sum(), (key, kernels))
    g_key_dir, g_ker_dir = torch.autograd.grad((direct * weight).sum(), (key, kernels))
    assert _rel(g_key_fft, g_key_dir) < 1e-4
    assert _rel(g_ker_fft, g_ker_dir) < 1e-4


def test_fft_correlation_does_not_wrap_around() -> None:
    # A single bright key pixel in the bottom-right corner must only reach the last valid output.
    key = torch.zeros(1, 1, 12, 10)
    key[0, 0, -1, -1] = 1.0
    kernels = torch.ones(1, 1, 1, 4, 4)
    out = fft_cross_correlation(key, kernels)[0, 0]
    assert out.shape == (9, 7)
    assert abs(float(out[-1, -1]) - 1.0) < 1e-5
    out[-1, -1] = 0.0
    assert float(out.abs().max()) < 1e-5


def test_transport_correlation_is_the_padded_conv_resized_and_cropped() -> None:
    """The reference's Transport.correlate: conv2d with padding crop / 2, bilinear resize to the key's size,
    crop the padding."""
    key, kernels = _inputs(b=2, r=3, c=3, hw=(40 + 16, 24 + 16), k=16)
    out = transport_correlation(key, kernels)
    expected = []
    for i in range(2):
        full = F.conv2d(key[i : i + 1], kernels[i], padding=8)
        assert full.shape[-2:] == (57, 41)
        expected.append(F.interpolate(full, size=(56, 40), mode="bilinear")[:, :, 8:-8, 8:-8])
    expected = torch.cat(expected)
    assert out.shape == expected.shape == (2, 3, 40, 24)
    assert _rel(out, expected) < 1e-5
    # The resize is not a no-op: the bottom-right outputs blend neighbours, unlike the plain valid correlation.
    assert _rel(fft_cross_correlation(key, kernels)[..., :40, :24], expected) > 1e-3
