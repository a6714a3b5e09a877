"""CLIPort two-stream agent: each of pick, key and query is a spatial + semantic two-stream net."""

from __future__ import annotations

import torch

from cliport.agents import register_agent
from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import CLIPConfig
from cliport.models.clip_backbone import FrozenCLIP, load_clip
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.streams import TwoStreamNet

PLACE_FEATURES = 3


@register_agent("two_stream", CLIPConfig)
class TwoStreamAgent(PickPlaceAgent):
    """Pick net fuses its streams by addition, key and query nets by ReLU + 1x1 conv; one shared CLIP."""

    uses_language = True
    weight_sources = ("clip_weights",)
    published_columns = {"cliport_table6_val_ravens": "cliport_wo_lang", "cliport_table1_test": "cliport_single"}

    def __init__(self, config: CLIPConfig, clip: FrozenCLIP | None = None) -> None:
        clip = clip if clip is not None else load_clip(config.clip_weights)
        pick = PickHead(TwoStreamNet(clip, 1, "add", config.width))
        place = PlaceHead(
            TwoStreamNet(clip, PLACE_FEATURES, "conv", config.width),
            TwoStreamNet(clip, PLACE_FEATURES, "conv", config.width),
            config.crop_size,
            config.n_rotations,
        )
        super().__init__(config, pick, place, clip)

    def sentence_features(self, lang: list[str] | None) -> torch.Tensor:
        """(B,) instructions -> (B, 1024) cached CLIP sentence features."""
        if lang is None or any(text is None for text in lang):
            raise ValueError("the two-stream agent needs an instruction for every observation")
        assert self.clip is not None
        return self.clip.sentence_features(list(lang))
