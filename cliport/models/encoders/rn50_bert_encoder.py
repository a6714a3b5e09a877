"""The frozen encoder of CLIPort's RN50-BERT ablation: an ImageNet ResNet-50 trunk and a DistilBERT sentence encoder.

Image trunk: torchvision's ResNet-50 architecture; the five levels are the stem (conv1, bn1, relu,
maxpool; 64 channels, stride 4) and layer1..layer4 (256, 512, 1024, 2048 channels at strides 4, 8, 16,
32). Its classifier head (``avgpool``, ``fc``) is dropped. Images are normalised with the ImageNet
mean and standard deviation, the statistics these weights were trained with. This is a deliberate
difference from the reference CLIPort, whose RN50-BERT ablation fed the ImageNet ResNet images
normalised with CLIP's statistics.

Sentence encoder: ``distilbert-base-uncased``'s architecture (``transformers.DistilBertModel``); a
sentence is the mean of ``last_hidden_state`` over its real tokens (768 wide; CLIPort takes the
plain mean over the tokens of one unpadded sentence, which is the same thing). The decoder puts a
trainable Linear 768 -> 1024 on it (:attr:`FrozenRN50BERT.sentence_projection`, CLIPort's
``text_fc``). DistilBERT reads at most :data:`MAX_TOKENS` tokens, ``[CLS]`` and ``[SEP]`` included.

The trunk and its weights: :mod:`cliport.models.encoders.rn50_trunk` (``rn50_weights``); DistilBERT, its tokenizer
and its weights: :mod:`cliport.models.encoders.distilbert` (``bert_weights``).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.distilbert import build_distilbert
from cliport.models.encoders.rn50_trunk import ResNet50Trunk, build_rn50_trunk

TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
SENTENCE_DIM = 768
SENTENCE_PROJECTION = 1024
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: DistilBERT reads at most this many tokens of an instruction, [CLS] and [SEP] included.
MAX_TOKENS = 512


class FrozenRN50BERT(FrozenEncoder):
    """Frozen ImageNet ResNet-50 trunk levels (stem, layer1..4) and DistilBERT sentence features (768)."""

    trunk_channels = TRUNK_CHANNELS
    sentence_dim = SENTENCE_DIM
    sentence_projection = SENTENCE_PROJECTION

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(
        self, trunk: ResNet50Trunk, bert: nn.Module, tokenizer: Any, rn50_source: str, bert_source: str
    ) -> None:
        super().__init__()
        self.trunk = trunk
        self.bert = bert
        self.tokenizer = tokenizer
        self.rn50_source = rn50_source
        self.bert_source = bert_source
        self.max_tokens = min(MAX_TOKENS, int(getattr(bert.config, "max_position_embeddings", MAX_TOKENS)))
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.freeze()

    def sources(self) -> dict[str, str]:
        return {"rn50_weights": self.rn50_source, "bert_weights": self.bert_source}

    def image_module(self) -> nn.Module:
        return self.trunk

    def count_tokens(self, text: str) -> int:
        """DistilBERT tokens of ``text``, [CLS] and [SEP] included (before truncation)."""
        return len(self.tokenizer(text, verbose=False)["input_ids"])

    def instruction_note(self, text: str) -> str | None:
        n_tokens = self.count_tokens(text)
        if n_tokens > self.max_tokens:
            return f"the instruction has {n_tokens} DistilBERT tokens; DistilBERT reads the first {self.max_tokens}"
        return None

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """RGB (N, 3, H, W) in [0, 1] -> five levels (N, C_i, H / s_i, W / s_i), ImageNet-normalised input."""
        x = ((rgb - self.mean) / self.std).to(self.image_dtype())
        return self.trunk(x)

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        """Instructions (B,) -> (B, 768): mean of DistilBERT's last hidden states over each one's real tokens."""
        batch = self.tokenizer(texts, padding=True, truncation=True, max_length=self.max_tokens, return_tensors="pt")
        device = self.mean.device
        ids = batch["input_ids"].to(device)
        mask = batch["attention_mask"].to(device)
        hidden = self.bert(input_ids=ids, attention_mask=mask).last_hidden_state  # (B, L, 768)
        weight = mask.unsqueeze(-1).to(hidden.dtype)
        return (hidden * weight).sum(dim=1) / weight.sum(dim=1).clamp(min=1)


def load_rn50_bert(rn50_source: str, bert_source: str) -> FrozenRN50BERT:
    """Load the frozen RN50-BERT encoder.

    ``rn50_source``: "imagenet", a torchvision resnet50 state-dict file, or "random"; ``bert_source``:
    "distilbert-base-uncased" (or another DistilBERT repo id), a ``save_pretrained`` folder, or "random".
    Raises :class:`RN50WeightsUnavailable` / :class:`BERTWeightsUnavailable` with one line naming the
    source and the problem.
    """
    trunk = build_rn50_trunk(rn50_source)
    bert, tokenizer = build_distilbert(bert_source)
    return FrozenRN50BERT(trunk, bert, tokenizer, rn50_source, bert_source)
