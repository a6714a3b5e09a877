"""CLIPort's two-stream net: a spatial ResNet45_10s stream and a semantic stream over a frozen encoder, fused.

Reproduces the reference's two-stream nets with lateral connections (cliport/models/streams/
two_stream_attention_lang_fusion.py, ``TwoStreamAttentionLangFusionLat``, and
two_stream_transport_lang_fusion.py, ``TwoStreamTransportLangFusionLat``): ``ResNet45_10s``
(cliport/models/resnet_lat.py) as stream one, ``CLIPLingUNetLat`` (or ``RN50BertLingUNetLat``) as stream
two, and ``FusionAdd`` (pick) or ``FusionConv`` (key, query) over their outputs.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from cliport.models.distinct_images import per_sample
from cliport.models.encoder_net import EncoderNet
from cliport.models.encoders.base import TRUNK_STRIDES, FrozenEncoder
from cliport.models.encoders.dense_clip import SIMILARITY_MAPS, PhraseBank, similarity_map
from cliport.models.fusion import AddFusion, ConvFusion
from cliport.models.lingunet import LingUNetLatDecoder
from cliport.models.preprocess import IN_CHANNELS, transporter_normalize
from cliport.models.resnet import ResNet45_10s

STRIDE = TRUNK_STRIDES[-1]


class TwoStreamNet(EncoderNet):
    """Spatial :class:`~cliport.models.resnet.ResNet45_10s` stream + semantic
    :class:`~cliport.models.lingunet.LingUNetLatDecoder` stream over the frozen encoder, fused.

    The spatial stream's six laterals feed the semantic decoder. ``conv_fusion``: False sums the two streams'
    outputs (the reference's pick nets); True applies ReLU + 1x1 conv (2 * out_ch -> out_ch, no bias) to
    [spatial, semantic] (its key and query nets). ``per_net_clip_stats``: see :class:`EncoderNet`;
    ``scale_up_mid``: see :class:`~cliport.models.lingunet.LingUNetLatDecoder`. ``similarity_maps``: the cosine of
    the frozen encoder's dense text-aligned embeddings (:mod:`~cliport.models.encoders.dense_clip`) with the
    instruction's and its phrases' text embeddings joins the spatial laterals (not the reference's net), the trunk
    reading the image at ``similarity_scale`` times its size for them. ``language_gates`` False (with the maps):
    the decoder's gates read a zero sentence feature, so the instruction enters through the maps alone. ``bank``
    (shared by an agent's nets): the maps are each text's probability against it, not cosines.
    A batch that repeats an image (a contrasting pair, a scene under several instructions) runs the spatial stream,
    the trunk and the decoder's image-only layers once per distinct image (:mod:`~cliport.models.distinct_images`).
    """

    bank: PhraseBank | None

    def __init__(
        self,
        encoder: FrozenEncoder,
        out_ch: int,
        width: float = 1.0,
        conv_fusion: bool = False,
        per_net_clip_stats: bool = False,
        scale_up_mid: bool = False,
        similarity_maps: bool = False,
        similarity_scale: float = 1.0,
        language_gates: bool = True,
        bank: PhraseBank | None = None,
    ) -> None:
        super().__init__(encoder, per_net_clip_stats)
        self.spatial = ResNet45_10s(IN_CHANNELS, out_ch, width)
        #: How many similarity maps join the laterals (:data:`~cliport.models.encoders.dense_clip.SIMILARITY_MAPS`).
        self.n_maps = SIMILARITY_MAPS if similarity_maps else 0
        self.similarity_scale = similarity_scale
        if not language_gates and not similarity_maps:
            raise ValueError("a net without language gates reads the instruction through similarity maps only")
        self.language_gates = language_gates
        if bank is not None and not similarity_maps:
            raise ValueError("a phrase bank makes probabilities of similarity maps: it needs them")
        object.__setattr__(self, "bank", bank)  # not a submodule: the agent owns it and saves it once
        self.logit_scale = encoder.logit_scale() if bank is not None else 0.0  # frozen: read once, no device sync
        self.semantic = LingUNetLatDecoder(
            encoder, out_ch, self.spatial.lateral_widths, width, scale_up_mid, extra_laterals=self.n_maps
        )
        self.fuse = ConvFusion(out_ch) if conv_fusion else AddFusion()

    def forward(self, x: torch.Tensor, sentence: torch.Tensor | None = None) -> torch.Tensor:
        """Raw (N, 6, H, W) (H, W multiples of 32), sentence (N, sentence_dim) -> (N, out_ch, H, W).

        With ``similarity_maps``, sentence is (N, (1 + n_maps) * sentence_dim): the feature the gates read, then
        n_maps unit text embeddings (:func:`~cliport.agents.sentences.similarity_texts`); their cosine with the
        frozen encoder's dense embeddings of the image joins every lateral."""
        if sentence is None:
            raise ValueError("the two-stream net needs a sentence feature")
        texts = None
        if self.n_maps:
            dim = self.encoder.sentence_dim
            if sentence.shape[1] != (1 + self.n_maps) * dim:
                raise ValueError(f"a net with similarity maps reads {(1 + self.n_maps) * dim} sentence channels")
            sentence, texts = sentence[:, :dim], sentence[:, dim:].unflatten(1, (self.n_maps, dim))
        if not self.language_gates:
            sentence = torch.zeros_like(sentence)
        distinct = self.distinct_inputs(x)
        images, index = (x, None) if distinct is None else (distinct.images, distinct.index)
        spatial, laterals = self.spatial(transporter_normalize(images))
        trunk = self.encoder_features(images)
        maps = None
        if texts is not None:
            maps = self.similarity(per_sample(self.dense_embeddings(images, trunk[-1]), index), texts)
        semantic = self.semantic(trunk, sentence, laterals, x.shape[-2:], index, maps)
        return self.fuse(per_sample(spatial, index), semantic)

    def similarity(self, dense: torch.Tensor, texts: torch.Tensor) -> torch.Tensor:
        """Dense embeddings (N, E, h, w) and K texts each (N, K, E) -> the maps the decoder reads (N, K, h, w):
        cosines, or with a phrase bank each text's probability against it."""
        if self.bank is None:
            return similarity_map(dense, texts)
        return self.bank(dense, texts, self.logit_scale)

    def dense_embeddings(self, images: torch.Tensor, layer4: torch.Tensor) -> torch.Tensor:
        """Raw images (M, 6, H, W) and their last trunk level (M, C, H/32, W/32) -> the frozen encoder's
        text-aligned embeddings (M, E, h, w), from the trunk re-run on the images resized by ``similarity_scale``
        (sides rounded to multiples of 32) where that is not 1."""
        if self.similarity_scale != 1.0:
            size = [max(STRIDE, round(side * self.similarity_scale / STRIDE) * STRIDE) for side in images.shape[-2:]]
            rgb = F.interpolate(images[:, :3], size=size, mode="bilinear", align_corners=False)
            stats = self.encoder_stats.as_dict() if self.encoder_stats is not None else None
            layer4 = self.encoder.image_features(rgb, stats)[-1]
        return self.encoder.dense_embeddings(layer4)
