import pytest
import torch

from cliport.models.encoders.clip_encoder import FrozenCLIP
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.resnet import ResNet43_8s, ResNet45_10s
from cliport.models.semantic import SemanticNet
from cliport.models.transporter import TransporterNet
from cliport.models.two_stream import TwoStreamNet


def _count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


def test_resnet43_real_size_shape_and_params() -> None:
    net = ResNet43_8s(6, 1)
    assert 9.8e6 < _count(net) < 9.85e6
    with torch.no_grad():
        assert net(torch.randn(1, 6, 320, 320)).shape == (1, 1, 320, 320)


def test_resnet45_laterals() -> None:
    net = ResNet45_10s(6, 3, width=0.125)
    out, laterals = net(torch.randn(2, 6, 64, 32))
    assert out.shape == (2, 3, 64, 32)
    # The inputs of the five decoder stages and of the head, which runs at twice the input size.
    assert [tuple(t.shape[1:]) for t in laterals] == [
        (128, 4, 2),
        (64, 8, 4),
        (32, 16, 8),
        (16, 32, 16),
        (8, 64, 32),
        (4, 128, 64),
    ]


def test_two_stream_real_size_params(clip: FrozenCLIP) -> None:
    pick = TwoStreamNet(clip, 1)
    key = TwoStreamNet(clip, 3, conv_fusion=True)
    assert 88e6 < _count(pick) < 96e6
    assert 88e6 < _count(key) < 96e6
    assert all(not p.requires_grad for p in clip.parameters())


@pytest.mark.parametrize("conv_fusion,out_ch", [(False, 1), (True, 3)])
def test_two_stream_shapes_and_language_dependence(clip: FrozenCLIP, conv_fusion: bool, out_ch: int) -> None:
    torch.manual_seed(0)
    net = TwoStreamNet(clip, out_ch, width=0.25, conv_fusion=conv_fusion)
    x = torch.rand(2, 6, 64, 96)
    sentences = clip.sentence_features(["pick the red block", "pick the blue block"])
    out = net(x, sentences)
    assert out.shape == (2, out_ch, 64, 96)
    # Random CLIP features are tiny, so the language effect is small at init, but it must be there
    # (checked before the stream fusion, whose ReLU may zero a random-init semantic output).
    _, laterals = net.spatial(x)
    trunk = clip.image_features(x[:, :3])
    semantic = net.semantic(trunk, sentences, laterals, (64, 96))
    assert not torch.equal(semantic, net.semantic(trunk, sentences.flip(0), laterals, (64, 96)))
    with pytest.raises(ValueError):
        net(x, None)


def test_two_stream_gradients_reach_every_trainable_parameter(clip: FrozenCLIP) -> None:
    net = TwoStreamNet(clip, 3, width=0.125, conv_fusion=True)
    out = net(torch.rand(1, 6, 64, 64), clip.sentence_features(["a"]))
    out.square().mean().backward()
    missing = [n for n, p in net.named_parameters() if p.requires_grad and p.grad is None]
    assert missing == []
    assert all(p.grad is None for p in clip.parameters())


def test_semantic_net_reads_rgb_and_language_only(clip: FrozenCLIP) -> None:
    """CLIP-only net: output at the input size, changed by the sentence and the colours, blind to height."""
    torch.manual_seed(0)
    net = SemanticNet(clip, 3, width=0.25)
    x = torch.rand(2, 6, 64, 96)
    sentences = clip.sentence_features(["pick the red block", "pick the blue block"])
    out = net(x, sentences)
    assert out.shape == (2, 3, 64, 96)
    assert not torch.equal(out, net(x, sentences.flip(0)))
    other_height = x.clone()
    other_height[:, 3:] = torch.rand(2, 3, 64, 96)
    assert torch.equal(out, net(other_height, sentences))
    other_rgb = x.clone()
    other_rgb[:, :3] = torch.rand(2, 3, 64, 96)
    assert not torch.allclose(out, net(other_rgb, sentences))
    assert not hasattr(net, "spatial") and not hasattr(net.semantic, "fusions")
    out.square().mean().backward()
    assert [n for n, p in net.named_parameters() if p.requires_grad and p.grad is None] == []
    with pytest.raises(ValueError):
        net(x, None)


def test_semantic_net_real_size_params(clip: FrozenCLIP) -> None:
    """The CLIP-only decoder alone: the two-stream net less its spatial stream and lateral fusions."""
    two = TwoStreamNet(clip, 3, conv_fusion=True)
    one = SemanticNet(clip, 3)
    lateral = sum(p.numel() for p in two.semantic.fusions.parameters())
    assert _count(one) == _count(two) - _count(two.spatial) - lateral - sum(p.numel() for p in two.fuse.parameters())


def test_pick_head_pads_to_square_and_crops_back() -> None:
    seen: list[tuple[int, ...]] = []

    class Recorder(torch.nn.Module):
        def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
            seen.append(tuple(x.shape))
            return x[:, 3:4]

    head = PickHead(Recorder())
    x = torch.rand(2, 6, 64, 32)
    logits = head(x)
    assert seen == [(2, 6, 64, 64)]
    # Equal up to the reference's 0-degree kornia resampling, which is not exact (float32 rounding).
    torch.testing.assert_close(logits, x[:, 3], rtol=0, atol=1e-5)


def test_place_head_shapes_and_unrotated_crop() -> None:
    head = PlaceHead(TransporterNet(3, 0.125), TransporterNet(3, 0.125), crop_size=16, n_rotations=6)
    x = torch.rand(2, 6, 64, 32)
    pick = torch.tensor([[10, 5], [40, 30]])
    assert head(x, pick).shape == (2, 6, 64, 32)
    padded = torch.nn.functional.pad(x, (8, 8, 8, 8))
    crops = head.query_crops(padded, pick).reshape(2, 6, 6, 16, 16)
    # Bin 0 is the plain crop centred on the pick pixel: padded rows u .. u + crop - 1.
    assert torch.allclose(crops[0, 0], padded[0, :, 10:26, 5:21], atol=1e-5)
    assert torch.allclose(crops[1, 0], padded[1, :, 40:56, 30:46], atol=1e-5)


def test_scale_up_mid_narrows_the_up_blocks_below_width_1_only(clip: FrozenCLIP) -> None:
    """scale_up_mid: the up-blocks' middle widths follow the width (128, 64, 32 at 0.125 over CLIP RN50) where the
    reference's rule keeps half the input (576, 288, 144); at width 1 both are the reference's net."""
    from cliport.models.lingunet import LingUNetLatDecoder

    def mids(net: torch.nn.Module) -> list[int]:
        return [up.conv[0].out_channels for up in net.semantic.ups]

    assert mids(TwoStreamNet(clip, 1, 0.125)) == [576, 288, 144]
    assert mids(TwoStreamNet(clip, 1, 0.125, scale_up_mid=True)) == [128, 64, 32]
    assert mids(SemanticNet(clip, 1, 0.125, scale_up_mid=True)) == [128, 64, 32]
    laterals = ResNet45_10s(6, 1).lateral_widths
    shapes = [
        {k: v.shape for k, v in LingUNetLatDecoder(clip, 1, laterals, 1.0, scale).state_dict().items()}
        for scale in (False, True)
    ]
    assert shapes[0] == shapes[1]


def test_agents_build_their_up_blocks_as_scale_up_mid_says() -> None:
    from cliport.agents import make_agent

    agent = make_agent("two_stream", {"width": 0.125, "clip_weights": "random", "scale_up_mid": True})
    nets = (agent.pick.net, agent.place.key_net, agent.place.query_net)
    assert all([up.conv[0].out_channels for up in net.semantic.ups] == [128, 64, 32] for net in nets)
    assert make_agent("two_stream", {"width": 0.125, "clip_weights": "random"}).config.scale_up_mid is False
