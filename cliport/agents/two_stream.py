"""CLIPort two-stream agent: each of pick, key and query is a spatial + semantic two-stream net."""

from __future__ import annotations

from cliport.agents import register_agent
from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import CLIPConfig
from cliport.models.clip_encoder import load_clip
from cliport.models.encoders import FrozenEncoder
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.streams import TwoStreamNet

PLACE_FEATURES = 3


@register_agent("two_stream", CLIPConfig)
class TwoStreamAgent(PickPlaceAgent):
    """Pick net fuses its streams by addition, key and query nets by ReLU + 1x1 conv; one shared CLIP."""

    uses_language = True
    weight_sources = ("clip_weights",)
    published_columns = {"cliport_table6_val_ravens": "cliport_wo_lang", "cliport_table1_test": "cliport_single"}

    def __init__(self, config: CLIPConfig, encoder: FrozenEncoder | None = None) -> None:
        encoder = encoder if encoder is not None else load_clip(config.clip_weights, config.semantic_encoder)
        own = isinstance(config, CLIPConfig) and config.per_net_clip_stats  # RN50-BERT has no CLIP
        pick = PickHead(TwoStreamNet(encoder, 1, "add", config.width, own_norm_stats=own))
        place = PlaceHead(
            TwoStreamNet(encoder, PLACE_FEATURES, "conv", config.width, own_norm_stats=own),
            TwoStreamNet(
                encoder, PLACE_FEATURES, "conv", config.width, samples_per_group=config.n_rotations, own_norm_stats=own
            ),
            config.crop_size,
            config.n_rotations,
        )
        super().__init__(config, pick, place, encoder)
