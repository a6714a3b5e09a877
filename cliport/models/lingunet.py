"""CLIPort's language-conditioned U-Net decoders over a frozen encoder's trunk (the semantic stream).

:class:`LingUNetDecoder` reproduces the reference's ``CLIPLingUNet`` (cliport/models/clip_lingunet.py) and
:class:`LingUNetLatDecoder` its ``CLIPLingUNetLat`` (cliport/models/clip_lingunet_lat.py); over an encoder
with a sentence projection (RN50-BERT) the latter is the reference's ``RN50BertLingUNetLat``
(cliport/models/rn50_bert_lingunet_lat.py), whose ``text_fc`` is ``sentence_fc`` here. The frozen CLIP (or
ResNet-50 and DistilBERT) the reference keeps inside these nets is the shared encoder here
(:mod:`cliport.models.encoders`), so a decoder takes the encoder's features as inputs.

The reference's attribute names are given as comments where ours differ (``reference_names`` maps each
tensor); ``lang_fuserN`` (``FusionMult``, no weights) is :func:`~cliport.models.fusion.language_gate`.
"""

from __future__ import annotations

import torch
from torch import nn

from cliport.models.blocks import UpBlock, UpStage, resize, scaled
from cliport.models.distinct_images import per_sample
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.fusion import LateralFusion, language_gate


def _widths(width: float) -> tuple[int, int, int, int, int, int, int]:
    """The decoder's widths 1024, 512, 256, 128, 64, 32, 16 scaled by ``width``."""
    w1024, w512, w256, w128, w64, w32, w16 = (scaled(c, width) for c in (1024, 512, 256, 128, 64, 32, 16))
    return w1024, w512, w256, w128, w64, w32, w16


def _sentence_fc(encoder: FrozenEncoder) -> nn.Linear | None:
    """The trainable projection of the sentence feature an encoder asks for (RN50-BERT: 768 -> 1024), or None."""
    if encoder.sentence_projection is None:
        return None
    return nn.Linear(encoder.sentence_dim, encoder.sentence_projection)


def _unet(
    encoder: FrozenEncoder, width: float, scale_up_mid: bool = False
) -> tuple[nn.Linear | None, nn.ModuleList, nn.Sequential, nn.ModuleList, nn.ModuleList]:
    """The parts both decoders share, built in this order (that of their random initialisation): the
    reference's text_fc (None over CLIP), lang_proj1..3, conv1, up1..3 and layer1..3. ``scale_up_mid``: the
    up-blocks' middle widths scale with ``width`` (see :class:`~cliport.agents.config.LanguageConfig`)."""
    _, c1, c2, c3, c4 = encoder.trunk_channels
    w1024, w512, w256, w128, w64, w32, w16 = _widths(width)
    sentence_fc = _sentence_fc(encoder)
    s = encoder.sentence_projection or encoder.sentence_dim
    lang_projs = nn.ModuleList([nn.Linear(s, w1024), nn.Linear(s, w512), nn.Linear(s, w256)])
    conv1 = nn.Sequential(nn.Conv2d(c4, w1024, 3, padding=1, bias=False), nn.ReLU(inplace=True))
    mids: list[int | None] = [None, None, None]  # in_ch // 2, the reference's
    if scale_up_mid:
        mids = [scaled((decoder + skip) // 2, width) for decoder, skip in ((1024, c3), (512, c2), (256, c1))]
    ups = nn.ModuleList([
        UpBlock(w1024 + c3, w512, mids[0]), UpBlock(w512 + c2, w256, mids[1]), UpBlock(w256 + c1, w128, mids[2])
    ])  # fmt: skip
    layers = nn.ModuleList([UpStage(w128, w64), UpStage(w64, w32), UpStage(w32, w16)])
    return sentence_fc, lang_projs, conv1, ups, layers


class LingUNetDecoder(nn.Module):
    """Reproduces the reference's ``CLIPLingUNet`` (cliport/models/clip_lingunet.py): the CLIP-only decoder.

    layer4 (/32) -> 3x3 conv 1024 (no bias) + ReLU -> [gate 1024, up + layer3 skip -> 512] (/16) ->
    [gate 512, up + layer2 -> 256] (/8) -> [gate 256, up + layer1 -> 128] (/4) -> stage 64, up (/2) ->
    stage 32, up (/1) -> stage 16, up (x2) -> 1x1 conv out, resized to the output size. A gate multiplies
    the map by a Linear projection of the sentence feature. The up-blocks' batch norms normalise per sample
    (:class:`~cliport.models.blocks.PerSampleBatchNorm2d`). The trunk's channels and the sentence width come
    from the encoder, whose sentence feature first goes through ``sentence_fc`` when it asks for a
    projection; ``width`` scales the decoder's own widths (``scale_up_mid``: the up-blocks' middle ones too).
    """

    def __init__(self, encoder: FrozenEncoder, out_ch: int, width: float = 1.0, scale_up_mid: bool = False) -> None:
        super().__init__()
        # text_fc, lang_proj1..3, conv1, up1..3, layer1..3
        self.sentence_fc, self.gates, self.bottleneck, self.ups, self.stages = _unet(encoder, width, scale_up_mid)
        self.out = nn.Conv2d(_widths(width)[-1], out_ch, 1)  # conv2

    def forward(
        self,
        trunk: list[torch.Tensor],
        sentence: torch.Tensor,
        out_size: tuple[int, int],
        index: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Trunk features [stem, layer1..4] of an (N, 3, H, W) image, sentence (N, sentence_dim), out_size (H, W)
        -> (N, out_ch, H, W). ``index`` (N,): the trunk features are of D distinct images, sample n's being
        ``index[n]`` (:mod:`~cliport.models.distinct_images`); the image-only layers run once per image."""
        _, l1, l2, l3, l4 = trunk
        lang_proj1, lang_proj2, lang_proj3 = self.gates
        up1, up2, up3 = self.ups
        layer1, layer2, layer3 = self.stages
        if self.sentence_fc is not None:
            sentence = self.sentence_fc(sentence)

        x = per_sample(self.bottleneck(l4), index)
        x = up1(language_gate(x, lang_proj1(sentence)), l3, index)
        x = up2(language_gate(x, lang_proj2(sentence)), l2, index)
        x = up3(language_gate(x, lang_proj3(sentence)), l1, index)
        x = layer1(x)
        x = layer2(x)
        x = layer3(x)
        return resize(self.out(x), out_size)


class LingUNetLatDecoder(nn.Module):
    """Reproduces the reference's ``CLIPLingUNetLat`` (cliport/models/clip_lingunet_lat.py) and, over the
    RN50-BERT encoder, its ``RN50BertLingUNetLat`` (cliport/models/rn50_bert_lingunet_lat.py): the semantic
    stream of the two-stream nets.

    :class:`LingUNetDecoder` (the same parts and names) with lateral connections: the output of each of its
    six up-steps is fused (concat -> ReLU -> 1x1 conv, :class:`~cliport.models.fusion.LateralFusion`) with the
    spatial stream's lateral of the same resolution. ``lateral_widths``: the six laterals' channels
    (strides 16, 8, 4, 2, 1, 1/2), :attr:`ResNet45_10s.lateral_widths <cliport.models.resnet.ResNet45_10s>`.
    ``extra_laterals``: that many more channels beside each lateral (the maps :meth:`forward` takes as ``extra``,
    resized to each lateral's resolution); 0 is the reference's net.
    """

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        lateral_widths: tuple[int, ...],
        width: float = 1.0,
        scale_up_mid: bool = False,
        extra_laterals: int = 0,
    ) -> None:
        super().__init__()
        _, w512, w256, w128, w64, w32, w16 = _widths(width)
        lat16, lat8, lat4, lat2, lat1, lat_half = (c + extra_laterals for c in lateral_widths)
        # text_fc, lang_proj1..3, conv1, up1..3, layer1..3
        self.sentence_fc, self.gates, self.bottleneck, self.ups, self.stages = _unet(encoder, width, scale_up_mid)
        self.fusions = nn.ModuleList(  # lat_fusion1..6
            [
                LateralFusion(w512 + lat16, w512),
                LateralFusion(w256 + lat8, w256),
                LateralFusion(w128 + lat4, w128),
                LateralFusion(w64 + lat2, w64),
                LateralFusion(w32 + lat1, w32),
                LateralFusion(w16 + lat_half, w16),
            ]
        )
        self.out = nn.Conv2d(w16, out_ch, 1)  # conv2

    def forward(
        self,
        trunk: list[torch.Tensor],
        sentence: torch.Tensor,
        laterals: list[torch.Tensor],
        out_size: tuple[int, int],
        index: torch.Tensor | None = None,
        extra: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Trunk features [stem, layer1..4] of an (N, 3, H, W) image, sentence (N, sentence_dim), the six
        spatial laterals (strides 16, 8, 4, 2, 1, 1/2), out_size (H, W) -> (N, out_ch, H, W). ``index`` (N,):
        the trunk features and laterals are of D distinct images, sample n's being ``index[n]``
        (:mod:`~cliport.models.distinct_images`); the image-only layers run once per image. ``extra``
        (N, extra_laterals, h, w): maps joined to every lateral, each resized to its resolution."""
        _, l1, l2, l3, l4 = trunk
        lang_proj1, lang_proj2, lang_proj3 = self.gates
        up1, up2, up3 = self.ups
        layer1, layer2, layer3 = self.stages
        lat_fusion1, lat_fusion2, lat_fusion3, lat_fusion4, lat_fusion5, lat_fusion6 = self.fusions
        lat16, lat8, lat4, lat2, lat1, lat_half = (
            per_sample(lateral, index) if extra is None
            else torch.cat([per_sample(lateral, index), resize(extra, lateral.shape[-2:])], dim=1)
            for lateral in laterals
        )  # fmt: skip
        if self.sentence_fc is not None:
            sentence = self.sentence_fc(sentence)

        x = per_sample(self.bottleneck(l4), index)
        x = up1(language_gate(x, lang_proj1(sentence)), l3, index)
        x = lat_fusion1(x, lat16)
        x = up2(language_gate(x, lang_proj2(sentence)), l2, index)
        x = lat_fusion2(x, lat8)
        x = up3(language_gate(x, lang_proj3(sentence)), l1, index)
        x = lat_fusion3(x, lat4)
        x = layer1(x)
        x = lat_fusion4(x, lat2)
        x = layer2(x)
        x = lat_fusion5(x, lat1)
        x = layer3(x)
        x = lat_fusion6(x, lat_half)
        return resize(self.out(x), out_size)
