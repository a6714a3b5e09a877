"""CLIPort two-stream agent: each of pick, key and query is a spatial + semantic two-stream net."""

from __future__ import annotations

from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import CLIPConfig, LanguageConfig
from cliport.agents.registry import register_agent
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.clip_encoder import load_clip
from cliport.models.heads import PLACE_FEATURES, PickHead, PlaceHead
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
        stats = isinstance(config, CLIPConfig) and config.per_net_clip_stats  # RN50-BERT has no CLIP
        maps = isinstance(config, CLIPConfig) and config.similarity_maps
        net = {
            "per_net_clip_stats": stats,
            "scale_up_mid": config.scale_up_mid,
            "similarity_maps": maps,
            "similarity_scale": config.similarity_scale if isinstance(config, CLIPConfig) else 1.0,
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
