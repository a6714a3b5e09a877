"""Per-net streams: the Transporter (spatial) stream, the semantic stream over a frozen encoder, and their fusion.

Every net here maps a raw input (N, 6, H, W) — RGB in [0, 1], height in metres repeated 3x — and an
optional sentence feature (N, sentence_dim) to an (N, out, H, W) map; each normalises its own input.
The nets compute what the reference CLIPort's nets compute given the same weights (see
docs/parity.md).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import LateralFusion, UpBlock, UpStage, resize, scaled
from cliport.models.encoders import FrozenEncoder, NormStats
from cliport.models.preprocess import IN_CHANNELS, transporter_normalize
from cliport.models.resnet import ResNet43_8s, ResNet45_10s


class TransporterNet(nn.Module):
    """Transporter Networks' net: normalisation + ResNet43_8s. Ignores language."""

    def __init__(self, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        self.resnet = ResNet43_8s(IN_CHANNELS, out_ch, width)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 8), sentence ignored -> (N, out_ch, H, W)."""
        return self.resnet(transporter_normalize(x))


class SemanticDecoder(nn.Module):
    """CLIPort's language-conditioned U-Net over a frozen trunk (the reference's ``CLIPLingUNetLat`` and,
    without laterals, ``CLIPLingUNet``).

    layer4 (/32) -> 3x3 conv 1024 (no bias) -> [gate 1024, up + layer3 skip -> 512] (/16) -> [gate 512,
    up + layer2 -> 256] (/8) -> [gate 256, up + layer1 -> 128] (/4) -> stage 64, up (/2) -> stage 32, up
    (/1) -> stage 16, up (x2) -> 1x1 conv out, resized to the input size. A gate multiplies the map by a
    Linear projection of the sentence feature. With ``lateral_widths`` (two-stream nets: the six laterals
    of :class:`ResNet45_10s`), the output of each of the six up-steps is fused with the spatial lateral of
    its resolution. The up-blocks' batch norms normalise per sample (:class:`PerSampleBatchNorm2d`;
    ``samples_per_group`` images form one sample: ``n_rotations`` in the query net). The trunk's channels
    and the sentence width come from the encoder; an encoder with ``sentence_projection`` gets a
    trainable Linear on the sentence feature before the gates.
    """

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        lateral_widths: tuple[int, ...] | None,
        width: float = 1.0,
        samples_per_group: int = 1,
    ) -> None:
        super().__init__()
        _, c1, c2, c3, c4 = encoder.trunk_channels
        w = [scaled(c, width) for c in (1024, 512, 256, 128, 64, 32, 16)]
        sentence_dim = encoder.sentence_dim
        self.sentence_fc = None
        if encoder.sentence_projection is not None:
            self.sentence_fc = nn.Linear(sentence_dim, encoder.sentence_projection)
            sentence_dim = encoder.sentence_projection
        self.gates = nn.ModuleList(nn.Linear(sentence_dim, ch) for ch in w[:3])
        self.bottleneck = nn.Sequential(nn.Conv2d(c4, w[0], 3, padding=1, bias=False), nn.ReLU(inplace=True))
        self.ups = nn.ModuleList(
            UpBlock(x + skip, out, samples_per_group)
            for x, skip, out in zip(w[:3], (c3, c2, c1), w[1:4], strict=True)
        )
        self.stages = nn.ModuleList(UpStage(i, o) for i, o in zip(w[3:6], w[4:7], strict=True))
        self.fusions = None
        if lateral_widths is not None:
            self.fusions = nn.ModuleList(
                LateralFusion(ch + lat, ch) for ch, lat in zip(w[1:7], lateral_widths, strict=True)
            )
        self.out = nn.Conv2d(w[6], out_ch, 1)

    def forward(
        self,
        trunk: list[torch.Tensor],
        sentence: torch.Tensor,
        laterals: list[torch.Tensor] | None,
        out_size: tuple[int, int],
    ) -> torch.Tensor:
        """Trunk features [stem, layer1..4] of an (N, 3, H, W) image, sentence (N, sentence_dim), six
        spatial laterals (strides 16, 8, 4, 2, 1, 1/2) or None, out_size (H, W) -> (N, out_ch, H, W)."""
        _, l1, l2, l3, l4 = trunk
        if self.sentence_fc is not None:
            sentence = self.sentence_fc(sentence)
        x = self.bottleneck(l4)
        for i, (gate, up, skip) in enumerate(zip(self.gates, self.ups, (l3, l2, l1), strict=True)):
            x = self._fuse(i, up(x * gate(sentence)[:, :, None, None], skip), laterals)
        for i, stage in enumerate(self.stages, start=3):
            x = self._fuse(i, stage(x), laterals)
        return resize(self.out(x), out_size)

    def _fuse(self, i: int, x: torch.Tensor, laterals: list[torch.Tensor] | None) -> torch.Tensor:
        if self.fusions is None:
            return x
        assert laterals is not None
        return self.fusions[i](x, laterals[i])


def encoder_features(net: TwoStreamNet | SemanticNet, x: torch.Tensor) -> list[torch.Tensor]:
    """The frozen encoder's trunk features of the RGB channels of x (N, 6, H, W), with the net's own
    batch-norm statistics when it keeps them: the reference's three CLIP copies (pick, key, query) each
    let their statistics drift in training, and its checkpoints act with each net's own. In training mode
    with ``train_encoder_norms`` set (the cliport recipe), the trunk's batch norms normalise each sample's
    images (``samples_per_group``) by their own statistics and update the net's running statistics."""
    stats = net.encoder_stats.as_dict() if net.encoder_stats is not None else None
    group = net.samples_per_group if net.training and net.train_encoder_norms else None
    return net.encoder.image_features(x[:, :3], stats, batch_stats_group=group)


class TwoStreamNet(nn.Module):
    """CLIPort net: spatial ResNet45_10s stream + frozen-encoder semantic stream, fused.

    The frozen encoder (CLIP, or RN50 + DistilBERT) is shared between nets and is not a trainable part
    of this one. ``fusion="add"`` sums the two streams' outputs (pick); ``fusion="conv"`` applies ReLU +
    1x1 conv without bias (2*out -> out) to [spatial, semantic] (key and query).
    ``samples_per_group``: see :class:`SemanticDecoder`. ``own_norm_stats``: the net keeps its own copy of
    the encoder trunk's batch-norm statistics (:class:`NormStats`, see :func:`encoder_features`).
    """

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        fusion: str,
        width: float = 1.0,
        samples_per_group: int = 1,
        own_norm_stats: bool = False,
    ) -> None:
        super().__init__()
        if fusion not in ("add", "conv"):
            raise ValueError(f"fusion must be 'add' or 'conv', got {fusion!r}")
        self.encoder = encoder
        self.encoder_stats = NormStats(encoder.norm_stats()) if own_norm_stats else None
        self.samples_per_group = samples_per_group
        self.train_encoder_norms = False  # see encoder_features; set by PickPlaceAgent.set_encoder_norm_training
        self.spatial = ResNet45_10s(IN_CHANNELS, out_ch, width)
        self.semantic = SemanticDecoder(encoder, out_ch, self.spatial.lateral_widths, width, samples_per_group)
        self.fuse = nn.Conv2d(2 * out_ch, out_ch, 1, bias=False) if fusion == "conv" else None

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the two-stream net needs a sentence feature")
        spatial, laterals = self.spatial(transporter_normalize(x))
        semantic = self.semantic(encoder_features(self, x), sentence, laterals, x.shape[-2:])
        if self.fuse is None:
            return spatial + semantic
        return self.fuse(F.relu(torch.cat([spatial, semantic], dim=1)))


class SemanticNet(nn.Module):
    """CLIPort's CLIP-only net: the frozen-encoder semantic stream alone (no spatial stream, no laterals).

    Reads only the RGB channels of its input; the height channels are not seen. ``own_norm_stats``: as
    for :class:`TwoStreamNet`.
    """

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        width: float = 1.0,
        samples_per_group: int = 1,
        own_norm_stats: bool = False,
    ) -> None:
        super().__init__()
        self.encoder = encoder
        self.encoder_stats = NormStats(encoder.norm_stats()) if own_norm_stats else None
        self.samples_per_group = samples_per_group
        self.train_encoder_norms = False  # see encoder_features
        self.semantic = SemanticDecoder(encoder, out_ch, None, width, samples_per_group)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the semantic net needs a sentence feature")
        return self.semantic(encoder_features(self, x), sentence, None, x.shape[-2:])
