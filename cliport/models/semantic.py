"""CLIPort's CLIP-only net: the semantic stream alone over a frozen encoder (no spatial stream, no laterals).

Reproduces the reference's ``CLIPLingUNet`` (cliport/models/clip_lingunet.py) as its
``clip_lingunet_transporter`` agent's ``OneStreamAttentionLangFusion`` and ``OneStreamTransportLangFusion``
use it (cliport/models/streams/one_stream_*_lang_fusion.py): :class:`~cliport.models.lingunet.LingUNetDecoder`
over the shared encoder's trunk features.
"""

from __future__ import annotations

import torch

from cliport.models.encoder_net import EncoderNet
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.lingunet import LingUNetDecoder


class SemanticNet(EncoderNet):
    """The semantic stream alone: LingUNetDecoder over the frozen encoder. Reads only the RGB channels of its
    input; the height channels are not seen. ``per_net_clip_stats``: see :class:`EncoderNet`."""

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        width: float = 1.0,
        per_net_clip_stats: bool = False,
        scale_up_mid: bool = False,
    ) -> None:
        super().__init__(encoder, per_net_clip_stats)
        self.semantic = LingUNetDecoder(encoder, out_ch, width, scale_up_mid)

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W)."""
        if sentence is None:
            raise ValueError("the semantic net needs a sentence feature")
        distinct = self.distinct_inputs(x)
        images, index = (x, None) if distinct is None else (distinct.images, distinct.index)
        return self.semantic(self.encoder_features(images), sentence, x.shape[-2:], index)
