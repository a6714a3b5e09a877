"""Per-net streams: the Transporter (spatial) stream, the semantic stream over a frozen encoder, and their fusion.

Every net here maps a raw input (N, 6, H, W) — RGB in [0, 1], height in metres repeated 3x — and an
optional sentence feature (N, sentence_dim) to an (N, out, H, W) map; each normalises its own input.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import ResidualStage, Upsample2x, scaled, upsample_bilinear
from cliport.models.encoders import FrozenEncoder
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


class DoubleConv(nn.Sequential):
    """(3x3 conv -> ReLU) x 2."""

    def __init__(self, in_ch: int, out_ch: int, mid_ch: int) -> None:
        super().__init__(
            nn.Conv2d(in_ch, mid_ch, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(mid_ch, out_ch, 3, padding=1),
            nn.ReLU(inplace=True),
        )


class SkipUp(nn.Module):
    """U-Net up-sampling block: bilinear x2, concatenate the skip feature, double conv."""

    def __init__(self, in_ch: int, skip_ch: int, out_ch: int) -> None:
        super().__init__()
        total = in_ch + skip_ch
        self.conv = DoubleConv(total, out_ch, total // 2)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """(N, in_ch, h, w), (N, skip_ch, H, W) -> (N, out_ch, H, W)."""
        x = upsample_bilinear(x, skip.shape[-2:])
        return self.conv(torch.cat([x, skip], dim=1))


class LanguageGate(nn.Module):
    """Projects the sentence feature to `ch` channels and multiplies it into a feature map."""

    def __init__(self, sentence_dim: int, ch: int) -> None:
        super().__init__()
        self.proj = nn.Linear(sentence_dim, ch)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor) -> torch.Tensor:
        """(N, ch, H, W), (N, sentence_dim) -> (N, ch, H, W)."""
        return x * self.proj(sentence)[:, :, None, None]


class LateralFusion(nn.Module):
    """concat(semantic, spatial lateral) -> ReLU -> 1x1 conv back to the semantic width."""

    def __init__(self, sem_ch: int, lat_ch: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(sem_ch + lat_ch, sem_ch, 1)

    def forward(self, x: torch.Tensor, lateral: torch.Tensor) -> torch.Tensor:
        """(N, sem_ch, H, W), (N, lat_ch, h, w) -> (N, sem_ch, H, W)."""
        if lateral.shape[-2:] != x.shape[-2:]:
            lateral = upsample_bilinear(lateral, x.shape[-2:])
        return self.conv(F.relu(torch.cat([x, lateral], dim=1)))


class SemanticDecoder(nn.Module):
    """Language-conditioned U-Net decoder over a frozen trunk, with lateral fusions from a spatial stream
    when it has one.

    layer4 (c4, /32) -> 3x3 conv 1024 -> [gate, up + layer3 skip -> 512] (/16) -> [gate, up + layer2
    -> 256] (/8) -> [gate, up + layer1 -> 128] (/4) -> 64, up (/2) -> 32, up (/1) -> 16 -> 1x1 conv out;
    with ``lateral_widths`` (two-stream nets), after each of the five 512..32 stages the matching spatial
    lateral is fused in; without them (CLIP-only), the stages follow each other directly. The trunk's
    channels and the sentence width come from the encoder; an encoder with ``sentence_projection``
    gets a trainable Linear on the sentence feature before the gates.
    """

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        lateral_widths: tuple[int, ...] | None,
        width: float = 1.0,
    ) -> None:
        super().__init__()
        _, c1, c2, c3, c4 = encoder.trunk_channels
        w = [scaled(c, width) for c in (1024, 512, 256, 128, 64, 32, 16)]
        sentence_dim = encoder.sentence_dim
        self.sentence_fc = None
        if encoder.sentence_projection is not None:
            self.sentence_fc = nn.Linear(sentence_dim, encoder.sentence_projection)
            sentence_dim = encoder.sentence_projection
        self.bottleneck = nn.Sequential(nn.Conv2d(c4, w[0], 3, padding=1), nn.ReLU(inplace=True))
        self.gates = nn.ModuleList(LanguageGate(sentence_dim, ch) for ch in w[:3])
        self.ups = nn.ModuleList([SkipUp(w[0], c3, w[1]), SkipUp(w[1], c2, w[2]), SkipUp(w[2], c1, w[3])])
        self.refine = nn.ModuleList([ResidualStage(w[3], w[4]), ResidualStage(w[4], w[5])])
        self.upsample = Upsample2x()
        self.fusions = None
        if lateral_widths is not None:
            self.fusions = nn.ModuleList(
                LateralFusion(ch, lat) for ch, lat in zip(w[1:6], lateral_widths, strict=True)
            )
        self.tail = ResidualStage(w[5], w[6])
        self.out = nn.Conv2d(w[6], out_ch, 1)

    def forward(
        self,
        trunk: list[torch.Tensor],
        sentence: torch.Tensor,
        laterals: list[torch.Tensor] | None,
        out_size: tuple[int, int],
    ) -> torch.Tensor:
        """Trunk features [stem, layer1..4] of an (N, 3, H, W) image, sentence (N, sentence_dim), five
        spatial laterals (strides 16, 8, 4, 2, 1) or None, out_size (H, W) -> (N, out_ch, H, W)."""
        _, l1, l2, l3, l4 = trunk
        if self.sentence_fc is not None:
            sentence = self.sentence_fc(sentence)
        fuse = list(self.fusions) if self.fusions is not None else [None] * 5
        lats = list(laterals) if laterals is not None else [None] * 5
        x = self.bottleneck(l4)
        for gate, up, fusion, lateral, skip in zip(self.gates, self.ups, fuse[:3], lats[:3], (l3, l2, l1), strict=True):
            x = up(gate(x, sentence), skip)
            if fusion is not None:
                x = fusion(x, lateral)
        for refine, fusion, lateral in zip(self.refine, fuse[3:], lats[3:], strict=True):
            x = self.upsample(refine(x))
            if fusion is not None:
                x = fusion(x, lateral)
        x = self.out(self.tail(x))
        if tuple(x.shape[-2:]) != tuple(out_size):
            x = upsample_bilinear(x, out_size)
        return x


class TwoStreamNet(nn.Module):
    """CLIPort net: spatial ResNet45_10s stream + frozen-encoder semantic stream, fused.

    The frozen encoder (CLIP, or RN50 + DistilBERT) is shared between nets and is not a trainable part
    of this one. ``fusion="add"``
    sums the two streams' outputs (pick); ``fusion="conv"`` applies ReLU + 1x1 conv (2*out -> out)
    (key and query).
    """

    def __init__(self, encoder: FrozenEncoder, out_ch: int, fusion: str, width: float = 1.0) -> None:
        super().__init__()
        if fusion not in ("add", "conv"):
            raise ValueError(f"fusion must be 'add' or 'conv', got {fusion!r}")
        self.encoder = encoder
        self.spatial = ResNet45_10s(IN_CHANNELS, out_ch, width)
        self.semantic = SemanticDecoder(encoder, out_ch, self.spatial.lateral_widths, width)
        self.fuse = nn.Conv2d(2 * out_ch, out_ch, 1) if fusion == "conv" else None

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the two-stream net needs a sentence feature")
        spatial, laterals = self.spatial(transporter_normalize(x))
        semantic = self.semantic(self.encoder.image_features(x[:, :3]), sentence, laterals, x.shape[-2:])
        if self.fuse is None:
            return spatial + semantic
        return self.fuse(F.relu(torch.cat([spatial, semantic], dim=1)))


class SemanticNet(nn.Module):
    """CLIPort's CLIP-only net: the frozen-encoder semantic stream alone (no spatial stream, no laterals).

    Reads only the RGB channels of its input; the height channels are not seen.
    """

    def __init__(self, encoder: FrozenEncoder, out_ch: int, width: float = 1.0) -> None:
        super().__init__()
        self.encoder = encoder
        self.semantic = SemanticDecoder(encoder, out_ch, None, width)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the semantic net needs a sentence feature")
        return self.semantic(self.encoder.image_features(x[:, :3]), sentence, None, x.shape[-2:])
