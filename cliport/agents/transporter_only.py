"""Transporter Networks baseline: three ResNet43_8s nets (pick, key, query), no language."""

from __future__ import annotations

from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import AgentConfig
from cliport.agents.registry import register_agent
from cliport.models.heads import PLACE_FEATURES, PickHead, PlaceHead
from cliport.models.transporter import TransporterNet


@register_agent("transporter_only")
class TransporterOnlyAgent(PickPlaceAgent):
    """Pick: 1-channel ResNet43_8s over the square-padded input. Place: 3-channel key and query nets."""

    published_columns = {
        "transporter_paper_test": "transporter",
        "cliport_table6_val_ravens": "transporter",
        "cliport_table1_test": "transporter_only",
    }

    def __init__(self, config: AgentConfig) -> None:
        pick = PickHead(TransporterNet(1, config.width), config.map_scale)
        place = PlaceHead(
            TransporterNet(PLACE_FEATURES, config.width),
            TransporterNet(PLACE_FEATURES, config.width),
            config.crop_size,
            config.n_rotations,
            config.map_scale,
        )
        super().__init__(config, pick, place)
