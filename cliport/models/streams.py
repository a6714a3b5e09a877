"""Per-net streams: the Transporter (spatial) stream, the CLIP semantic stream, and their fusion.

Every net here maps a raw input (N, 6, H, W) — RGB in [0, 1], height in metres repeated 3x — and an
optional sentence feature (N, 1024) to an (N, out, H, W) map; each normalises its own input.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from cliport.models.blocks import ResidualStage, Upsample2x, scaled, upsample_bilinear
from cliport.models.clip_backbone import SENTENCE_DIM, TRUNK_CHANNELS, FrozenCLIP
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

    def __init__(self, ch: int) -> None:
        super().__init__()
        self.proj = nn.Linear(SENTENCE_DIM, ch)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor) -> torch.Tensor:
        """(N, ch, H, W), (N, 1024) -> (N, ch, H, W)."""
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
    """Language-conditioned U-Net decoder over the CLIP trunk with lateral fusions from the spatial stream.

    layer4 (2048, /32) -> 3x3 conv 1024 -> [gate, up + layer3 skip -> 512] (/16) -> [gate, up + layer2
    -> 256] (/8) -> [gate, up + layer1 -> 128] (/4) -> 64, up (/2) -> 32, up (/1) -> 16 -> 1x1 conv out;
    after each of the five 512..32 stages the matching spatial lateral is fused in.
    """

    def __init__(self, out_ch: int, lateral_widths: tuple[int, ...], width: float = 1.0) -> None:
        super().__init__()
        _, c1, c2, c3, c4 = TRUNK_CHANNELS
        w = [scaled(c, width) for c in (1024, 512, 256, 128, 64, 32, 16)]
        self.bottleneck = nn.Sequential(nn.Conv2d(c4, w[0], 3, padding=1), nn.ReLU(inplace=True))
        self.gates = nn.ModuleList(LanguageGate(ch) for ch in w[:3])
        self.ups = nn.ModuleList([SkipUp(w[0], c3, w[1]), SkipUp(w[1], c2, w[2]), SkipUp(w[2], c1, w[3])])
        self.refine = nn.ModuleList([ResidualStage(w[3], w[4]), ResidualStage(w[4], w[5])])
        self.upsample = Upsample2x()
        self.fusions = nn.ModuleList(LateralFusion(ch, lat) for ch, lat in zip(w[1:6], lateral_widths, strict=True))
        self.tail = ResidualStage(w[5], w[6])
        self.out = nn.Conv2d(w[6], out_ch, 1)

    def forward(self, trunk: list[torch.Tensor], sentence: torch.Tensor, laterals: list[torch.Tensor]) -> torch.Tensor:
        """CLIP trunk features [stem, layer1..4] of an (N, 3, H, W) image, sentence (N, 1024), five
        spatial laterals (strides 16, 8, 4, 2, 1) -> (N, out_ch, H, W)."""
        _, l1, l2, l3, l4 = trunk
        x = self.bottleneck(l4)
        for gate, up, fusion, lateral, skip in zip(
            self.gates, self.ups, self.fusions[:3], laterals[:3], (l3, l2, l1), strict=True
        ):
            x = fusion(up(gate(x, sentence), skip), lateral)
        for refine, fusion, lateral in zip(self.refine, self.fusions[3:], laterals[3:], strict=True):
            x = fusion(self.upsample(refine(x)), lateral)
        x = self.out(self.tail(x))
        out_size = laterals[-1].shape[-2:]
        if x.shape[-2:] != out_size:
            x = upsample_bilinear(x, out_size)
        return x


class TwoStreamNet(nn.Module):
    """CLIPort net: spatial ResNet45_10s stream + frozen-CLIP semantic stream, fused.

    The frozen CLIP is shared between nets and is not a trainable part of this one. ``fusion="add"``
    sums the two streams' outputs (pick); ``fusion="conv"`` applies ReLU + 1x1 conv (2*out -> out)
    (key and query).
    """

    def __init__(self, clip: FrozenCLIP, out_ch: int, fusion: str, width: float = 1.0) -> None:
        super().__init__()
        if fusion not in ("add", "conv"):
            raise ValueError(f"fusion must be 'add' or 'conv', got {fusion!r}")
        self.clip = clip
        self.spatial = ResNet45_10s(IN_CHANNELS, out_ch, width)
        self.semantic = SemanticDecoder(out_ch, self.spatial.lateral_widths, width)
        self.fuse = nn.Conv2d(2 * out_ch, out_ch, 1) if fusion == "conv" else None

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, 1024) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the two-stream net needs a sentence feature")
        spatial, laterals = self.spatial(transporter_normalize(x))
        semantic = self.semantic(self.clip.image_features(x[:, :3]), sentence, laterals)
        if self.fuse is None:
            return spatial + semantic
        return self.fuse(F.relu(torch.cat([spatial, semantic], dim=1)))
