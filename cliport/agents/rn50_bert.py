"""CLIPort's RN50-BERT ablation: the two-stream design with an ImageNet ResNet-50 image trunk and a
DistilBERT sentence encoder in place of CLIP's two encoders (both frozen)."""

from __future__ import annotations

from cliport.agents.config import RN50BERTConfig
from cliport.agents.registry import register_agent
from cliport.agents.two_stream import TwoStreamAgent
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.rn50_bert_encoder import load_rn50_bert


@register_agent("rn50_bert")
class RN50BERTAgent(TwoStreamAgent):
    """CLIPort's two-stream nets over a frozen ImageNet ResNet-50 and DistilBERT (one instance shared);
    each net's decoder projects the 768-wide sentence feature to 1024 (trainable) before its gates."""

    published_columns = {"cliport_table1_test": "rn50_bert"}

    def __init__(self, config: RN50BERTConfig, encoder: FrozenEncoder | None = None) -> None:
        encoder = encoder if encoder is not None else load_rn50_bert(config.rn50_weights, config.bert_weights)
        super().__init__(config, encoder)
