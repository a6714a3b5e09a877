"""CLIPort two-stream agent: each of pick, key and query is a spatial + semantic two-stream net."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from cliport.agents import decode, sentences
from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import CLIPConfig, LanguageConfig
from cliport.agents.registry import register_agent
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.clip_encoder import load_clip
from cliport.models.encoders.dense_clip import PhraseBank, instruction_phrases
from cliport.models.heads import PLACE_FEATURES, PickHead, PlaceHead, grow_logits, pad_square, shrink_map
from cliport.models.two_stream import TwoStreamNet


@register_agent("two_stream")
class TwoStreamAgent(PickPlaceAgent):
    """Pick net fuses its streams by addition, key and query nets by ReLU + 1x1 conv; one shared CLIP."""

    uses_language = True
    published_columns = {"cliport_table6_val_ravens": "cliport_wo_lang", "cliport_table1_test": "cliport_single"}

    def __init__(self, config: LanguageConfig, encoder: FrozenEncoder | None = None) -> None:
        if encoder is None:
            if not isinstance(config, CLIPConfig):
                raise TypeError(f"{type(config).__name__} names no CLIP: pass the encoder")
            encoder = load_clip(config.clip_weights, config.semantic_encoder)
        clip = config if isinstance(config, CLIPConfig) else None  # RN50-BERT has no CLIP
        bank = PhraseBank(encoder.sentence_dim) if clip is not None and clip.similarity_bank else None
        net: dict[str, Any] = {
            "per_net_clip_stats": clip is not None and clip.per_net_clip_stats,
            "scale_up_mid": config.scale_up_mid,
            "similarity_maps": clip is not None and clip.similarity_maps,
            "similarity_scale": clip.similarity_scale if clip is not None else 1.0,
            "language_gates": clip.language_gates if clip is not None else True,
            "bank": bank,
        }
        pick = PickHead(TwoStreamNet(encoder, 1, config.width, **net), config.map_scale)
        place = PlaceHead(
            TwoStreamNet(encoder, PLACE_FEATURES, config.width, conv_fusion=True, **net),
            TwoStreamNet(encoder, PLACE_FEATURES, config.width, conv_fusion=True, **net),
            config.crop_size,
            config.n_rotations,
            config.map_scale,
        )
        super().__init__(config, pick, place, encoder)
        self.phrase_bank = bank

    @torch.no_grad()
    def similarity_heatmaps(self, obs: dict[str, np.ndarray], instruction: str) -> dict[str, np.ndarray]:
        """With ``similarity_maps``: the maps of the instruction and of its phrases that the pick net reads for
        ``obs`` (cosines, or probabilities against its phrase bank), from its map shrunk by ``map_scale`` and padded
        to a square as the pick head does, cropped and grown back to the observation's (H, W); ``{}`` without."""
        net = self.pick.net
        if not isinstance(net, TwoStreamNet) or not net.n_maps:
            return {}
        self.eval()
        x, _ = decode.act_input([obs], self.device)
        small = shrink_map(x, self.pick.map_scale)
        square, (top, left) = pad_square(small)
        texts = [instruction, *instruction_phrases(instruction)]
        embeddings = sentences.similarity_texts(net.encoder, [instruction]).unflatten(1, (net.n_maps, -1))
        maps = net.similarity(net.dense_embeddings(square, net.encoder_features(square)[-1]), embeddings)
        maps = F.interpolate(maps, size=square.shape[-2:], mode="bilinear", align_corners=False)
        maps = grow_logits(maps[..., top : top + small.shape[-2], left : left + small.shape[-1]], x.shape[-2:])
        return {text: maps[0, i].float().cpu().numpy() for i, text in enumerate(texts)}
