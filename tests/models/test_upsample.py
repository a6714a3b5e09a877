"""The elementwise bilinear x2 stencil is F.interpolate's function, and every net is unchanged by it."""

from collections.abc import Iterator

import pytest
import torch
import torch.nn.functional as F

from cliport.models import blocks
from cliport.models.blocks import set_upsample_mode, upsample2x_stencil, upsample_bilinear
from cliport.models.clip_backbone import FrozenCLIP, load_clip
from cliport.models.streams import TransporterNet, TwoStreamNet

WIDTH = 0.125


def _interpolate(x: torch.Tensor) -> torch.Tensor:
    return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)


@pytest.fixture
def restore_mode() -> Iterator[None]:
    yield
    set_upsample_mode("auto")


@pytest.fixture(scope="module")
def clip() -> FrozenCLIP:
    return load_clip("random")


@pytest.mark.parametrize("shape", [(2, 3, 5, 7), (1, 4, 1, 6), (3, 2, 40, 1), (36, 8, 16, 16), (1, 16, 12, 7)])
def test_stencil_equals_interpolate(shape: tuple[int, ...]) -> None:
    x = torch.randn(shape, generator=torch.Generator().manual_seed(0)) * 3
    expected = _interpolate(x)
    torch.testing.assert_close(upsample2x_stencil(x), expected, rtol=0, atol=1e-6)
    channels_last = upsample2x_stencil(x.contiguous(memory_format=torch.channels_last))
    torch.testing.assert_close(channels_last, expected, rtol=0, atol=1e-6)
    if shape[2] > 1 and shape[3] > 1 and shape[1] > 1:
        assert channels_last.is_contiguous(memory_format=torch.channels_last)


def test_stencil_gradient_equals_interpolate() -> None:
    x = torch.randn(2, 3, 6, 5, generator=torch.Generator().manual_seed(1), requires_grad=True)
    grad_out = torch.randn(2, 3, 12, 10, generator=torch.Generator().manual_seed(2))
    (expected,) = torch.autograd.grad(_interpolate(x), x, grad_out)
    (got,) = torch.autograd.grad(upsample2x_stencil(x), x, grad_out)
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-6)


def test_dispatch(restore_mode: None) -> None:
    x = torch.randn(1, 2, 3, 4)
    with pytest.raises(ValueError):
        set_upsample_mode("nearest")
    set_upsample_mode("interpolate")
    assert not blocks._use_stencil(x)
    set_upsample_mode("auto")
    assert not blocks._use_stencil(x)  # the native CPU kernel is the faster one on a CPU
    assert blocks._use_stencil(torch.empty(1, 2, 3, 4, device="meta"))
    set_upsample_mode("stencil")
    assert blocks._use_stencil(x)
    # Non-x2 sizes always fall back to F.interpolate.
    torch.testing.assert_close(
        upsample_bilinear(x, (5, 9)), F.interpolate(x, size=(5, 9), mode="bilinear", align_corners=False)
    )


def _both_ways(
    net: torch.nn.Module, x: torch.Tensor, sentence: torch.Tensor | None, monkeypatch: pytest.MonkeyPatch
) -> tuple[torch.Tensor, torch.Tensor]:
    """Net output with F.interpolate (the old code) and with the stencil; the stencil run must make no
    F.interpolate call, i.e. every up-sampling of these shapes is an exact x2."""
    calls = []
    original = F.interpolate

    def counting(*args: object, **kwargs: object) -> torch.Tensor:
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(F, "interpolate", counting)
    with torch.no_grad():
        set_upsample_mode("interpolate")
        old = net(x, sentence)
        assert calls, "the old path should call F.interpolate"
        calls.clear()
        set_upsample_mode("stencil")
        new = net(x, sentence)
    assert not calls, "an up-sampling of these shapes was not an exact x2"
    return old, new


# The evaluation shapes: 320x160 padded to a 320x320 square (pick), padded by 32 to 384x224 (key) and the
# 64x64 query crops.
SHAPES = {"pick": (1, 320, 320), "key": (1, 384, 224), "query": (2, 64, 64)}


@pytest.mark.parametrize("which", list(SHAPES))
def test_transporter_net_unchanged(which: str, monkeypatch: pytest.MonkeyPatch, restore_mode: None) -> None:
    torch.manual_seed(0)
    n, h, w = SHAPES[which]
    net = TransporterNet(1 if which == "pick" else 3, WIDTH).eval()
    x = torch.rand(n, 6, h, w)
    old, new = _both_ways(net, x, None, monkeypatch)
    torch.testing.assert_close(new, old, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("which", list(SHAPES))
def test_two_stream_net_unchanged(
    which: str, clip: FrozenCLIP, monkeypatch: pytest.MonkeyPatch, restore_mode: None
) -> None:
    torch.manual_seed(0)
    n, h, w = SHAPES[which]
    net = TwoStreamNet(clip, 1 if which == "pick" else 3, "add" if which == "pick" else "conv", WIDTH).eval()
    x = torch.rand(n, 6, h, w)
    sentence = torch.randn(n, 1024)
    old, new = _both_ways(net, x, sentence, monkeypatch)
    scale = old.abs().max().item()
    torch.testing.assert_close(new, old, rtol=1e-5, atol=1e-5 * max(1.0, scale))
