import pytest
import torch
from torch import nn

from cliport.models.blocks import ConvBlock, PerSampleBatchNorm2d, UpBlock, resize, upsample2x


def test_upsample_is_the_align_corners_true_bilinear() -> None:
    x = torch.randn(2, 3, 5, 7)
    expected = nn.UpsamplingBilinear2d(scale_factor=2)(x)
    assert torch.equal(upsample2x(x), expected)
    # Corners are kept exactly (align_corners=True), unlike align_corners=False at the same size.
    up = upsample2x(x)
    assert torch.equal(up[..., 0, 0], x[..., 0, 0]) and torch.equal(up[..., -1, -1], x[..., -1, -1])


def test_resize_back_from_twice_the_size_is_a_2x2_average() -> None:
    x = torch.randn(1, 2, 8, 6)
    torch.testing.assert_close(resize(x, (4, 3)), nn.functional.avg_pool2d(x, 2), rtol=0, atol=1e-6)
    assert resize(x, (8, 6)) is x


def test_conv_block_strides_on_its_3x3_conv() -> None:
    block = ConvBlock(4, (8, 8, 8), stride=2)
    assert block.conv1.stride == (1, 1) and block.conv2.stride == (2, 2) and block.shortcut.stride == (2, 2)
    assert all(m.bias is None for m in block.modules() if isinstance(m, nn.Conv2d))
    assert block(torch.randn(1, 4, 10, 6)).shape == (1, 8, 5, 3)


def _reference_steps(norm: nn.BatchNorm2d, samples: list[torch.Tensor]) -> list[torch.Tensor]:
    """What the reference does: one training-mode batch-norm call per sample (batch 1, or its crops)."""
    return [norm(s) for s in samples]


@pytest.mark.parametrize("group", [1, 4])
def test_per_sample_batch_norm_equals_one_call_per_sample(group: int) -> None:
    torch.manual_seed(0)
    x = torch.randn(3 * group, 5, 6, 4) * 3 + 1
    ours = PerSampleBatchNorm2d(5, samples_per_group=group)
    reference = nn.BatchNorm2d(5)
    with torch.no_grad():
        for norm in (ours, reference):
            norm.weight.copy_(torch.linspace(0.5, 2, 5))
            norm.bias.copy_(torch.linspace(-1, 1, 5))
    expected = torch.cat(_reference_steps(reference, list(x.split(group))))
    torch.testing.assert_close(ours(x), expected, rtol=1e-5, atol=1e-5)
    # The running statistics end where three sequential batch-1 steps leave them.
    torch.testing.assert_close(ours.running_mean, reference.running_mean, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(ours.running_var, reference.running_var, rtol=1e-5, atol=1e-6)
    assert ours.num_batches_tracked.item() == reference.num_batches_tracked.item() == 3


def test_per_sample_batch_norm_keeps_batch_mates_independent_in_eval_mode_too() -> None:
    torch.manual_seed(0)
    norm = PerSampleBatchNorm2d(3, samples_per_group=2).eval()
    a, b = torch.randn(2, 3, 4, 4), torch.randn(2, 3, 4, 4) * 10
    stats = norm.running_mean.clone(), norm.running_var.clone()
    alone = norm(a)
    together = norm(torch.cat([a, b]))
    torch.testing.assert_close(together[:2], alone, rtol=0, atol=1e-6)
    # Eval mode still normalises with the call's own statistics, never the running ones.
    assert abs(alone.mean().item()) < 1e-5
    assert torch.equal(norm.running_mean, stats[0]) and torch.equal(norm.running_var, stats[1])


def test_per_sample_batch_norm_names_a_batch_that_does_not_split() -> None:
    with pytest.raises(ValueError, match="5 images do not split into groups of 2"):
        PerSampleBatchNorm2d(3, samples_per_group=2)(torch.randn(5, 3, 4, 4))


def test_up_block_concatenates_skip_first_and_pads_odd_sizes() -> None:
    torch.manual_seed(0)
    up = UpBlock(6, 4)
    x, skip = torch.randn(1, 2, 3, 3), torch.randn(1, 4, 7, 6)
    out = up(x, skip)
    assert out.shape == (1, 4, 7, 6)
    # The first conv sees [skip, upsampled x]: zeroing its skip-facing weights removes the skip's effect.
    with torch.no_grad():
        up.conv[0].weight[:, :4] = 0
    assert torch.equal(up(x, skip), up(x, torch.randn_like(skip)))


def test_up_block_over_a_frozen_skip_trains_as_plain_autograd_would() -> None:
    """The backward that leaves out the frozen skip's gradient gives the same weight gradients (bitwise) and the
    same gradient for the decoder's own input (to rounding) as autograd over the concatenation."""
    torch.manual_seed(0)
    up = UpBlock(40 + 8, 6)
    x, skip = torch.randn(1, 8, 4, 5, requires_grad=True), torch.randn(1, 40, 9, 10)
    target = torch.randn(1, 6, 9, 10)

    def gradients(joined_by_autograd: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        up.zero_grad(set_to_none=True)
        x.grad = None
        s = skip.clone().requires_grad_(True) if joined_by_autograd else skip  # a skip needing its gradient
        out = up(x, s)
        (out * target).sum().backward()
        return out.detach(), [x.grad.clone(), *(p.grad.clone() for p in up.parameters())]

    out, grads = gradients(joined_by_autograd=False)
    plain_out, plain_grads = gradients(joined_by_autograd=True)
    assert torch.equal(out, plain_out)
    torch.testing.assert_close(grads[0], plain_grads[0], rtol=1e-5, atol=1e-6)
    assert all(torch.equal(a, b) for a, b in zip(grads[1:], plain_grads[1:], strict=True))
    with torch.no_grad():  # acting: the plain forward, the same values
        assert torch.equal(up(x, skip), out)
