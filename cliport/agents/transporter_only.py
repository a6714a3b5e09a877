"""Transporter Networks baseline: three ResNet43_8s nets (pick, key, query), no language."""

from __future__ import annotations

from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import TransporterOnlyConfig
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.streams import TransporterNet

PLACE_FEATURES = 3


class TransporterOnlyAgent(PickPlaceAgent):
    """Pick: 1-channel ResNet43_8s over the square-padded input. Place: 3-channel key and query nets."""

    name = "transporter_only"

    def __init__(self, config: TransporterOnlyConfig) -> None:
        pick = PickHead(TransporterNet(1, config.width))
        place = PlaceHead(
            TransporterNet(PLACE_FEATURES, config.width),
            TransporterNet(PLACE_FEATURES, config.width),
            config.crop_size,
            config.n_rotations,
        )
        super().__init__(config, pick, place)
