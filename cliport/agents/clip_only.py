"""CLIPort's CLIP-only ablation: the semantic stream alone in pick, key and query (no spatial stream)."""

from __future__ import annotations

from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import CLIPConfig
from cliport.agents.registry import register_agent
from cliport.errors import ConfigError
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.clip_encoder import load_clip
from cliport.models.heads import PLACE_FEATURES, PickHead, PlaceHead
from cliport.models.semantic import SemanticNet


@register_agent("clip_only")
class CLIPOnlyAgent(PickPlaceAgent):
    """Frozen CLIP RN50 trunk and sentence feature, language-gated U-Net decoders; sees RGB only (no height)."""

    uses_language = True
    published_columns = {"cliport_table1_test": "clip_only"}

    def __init__(self, config: CLIPConfig, encoder: FrozenEncoder | None = None) -> None:
        if config.similarity_maps:
            raise ConfigError("similarity_maps is an option of the two_stream agent, whose laterals the maps join")
        encoder = encoder if encoder is not None else load_clip(config.clip_weights, config.semantic_encoder)
        net = {"per_net_clip_stats": config.per_net_clip_stats, "scale_up_mid": config.scale_up_mid}
        pick = PickHead(SemanticNet(encoder, 1, config.width, **net), config.map_scale)
        place = PlaceHead(
            SemanticNet(encoder, PLACE_FEATURES, config.width, **net),
            SemanticNet(encoder, PLACE_FEATURES, config.width, **net),
            config.crop_size,
            config.n_rotations,
            config.map_scale,
        )
        super().__init__(config, pick, place, encoder)
