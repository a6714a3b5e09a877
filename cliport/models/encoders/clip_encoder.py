"""One frozen open_clip model shared by every semantic stream: image trunk features and sentence features.

The model is any name of ``open_clip.list_models()`` (``--semantic-encoder NAME``, checked first by
:mod:`cliport.models.encoders.clip_registry`); the default is ``RN50-quickgelu`` (CLIPort's CLIP RN50).

Image trunks (five levels at strides 4, 4, 8, 16, 32, see :class:`FrozenCLIP`):

- open_clip's ResNets (``RN50``, ``RN101``, ``RN50x4``, ... and their ``-quickgelu`` twins): the stem
  and layer1..layer4, as CLIPort uses them.
- open_clip's ViTs (``ViT-B-16``, ``ViT-B-32``, ``ViT-L-14``, ...): the patch tokens of four blocks
  spread evenly through the depth, resampled to the four strides (:func:`cliport.models.encoders.clip_vit.vit_levels`).
- Image towers that come from timm (``ViT-B-16-SigLIP*``, ``convnext_*``, ``EVA*``, ``ViTamin*``, ...)
  are not supported: :class:`UnsupportedEncoderError` says so before the weights are fetched.

Weights: :mod:`cliport.models.encoders.clip_weights` (pretrained tags, local files, "random"). Text: the model's own
tokenizer and context length, :mod:`cliport.models.encoders.clip_tokenizer`.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.clip_registry import MODEL_NAME, UnsupportedEncoderError, check_model_name
from cliport.models.encoders.clip_tokenizer import count_tokens, load_tokenizer
from cliport.models.encoders.clip_vit import vit_block_indices, vit_levels
from cliport.models.encoders.clip_weights import build_clip_model
from cliport.models.encoders.dense_clip import dense_embeddings

# The default model's sentence width and trunk channels (stem, layer1..layer4 at strides 4, 4, 8, 16, 32);
# other models have their own, see FrozenCLIP.trunk_channels and FrozenCLIP.sentence_dim.
SENTENCE_DIM = 1024
TRUNK_CHANNELS = (64, 256, 512, 1024, 2048)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def _trunk_channels(visual: nn.Module) -> tuple[int, int, int, int, int]:
    """Channels of the five trunk levels, read from the image tower's modules (no forward pass)."""
    from open_clip.modified_resnet import ModifiedResNet
    from open_clip.transformer import VisionTransformer

    if isinstance(visual, ModifiedResNet):
        layers = (visual.layer1, visual.layer2, visual.layer3, visual.layer4)
        return (visual.conv3.out_channels, *(layer[-1].conv3.out_channels for layer in layers))
    if isinstance(visual, VisionTransformer):
        return (visual.transformer.width,) * 5
    raise UnsupportedEncoderError(f"no trunk adapter for the image tower {type(visual).__name__}")


def trunk_levels(
    visual: Any, images: torch.Tensor, vit_blocks: tuple[int, int, int, int] | None = None
) -> list[torch.Tensor]:
    """An open_clip image tower's five trunk levels from normalised images (N, 3, H, W), strides 4, 4, 8, 16, 32:
    a ModifiedResNet's stem and layer1..4, or a ViT's :func:`~cliport.models.encoders.clip_vit.vit_levels` of
    ``vit_blocks`` (default: :func:`~cliport.models.encoders.clip_vit.vit_block_indices` of its depth)."""
    from open_clip.transformer import VisionTransformer

    if isinstance(visual, VisionTransformer):
        return vit_levels(visual, vit_blocks or vit_block_indices(len(visual.transformer.resblocks)), images)
    return visual.forward_intermediates(images, intermediates_only=True)["image_intermediates"]


def _sentence_dim(model: nn.Module) -> int | None:
    """Width of ``encode_text``'s output read from the text tower's modules (None: not readable)."""
    projection = getattr(model, "text_projection", None)
    if isinstance(projection, nn.Linear):
        return projection.out_features
    if isinstance(projection, torch.Tensor):
        return int(projection.shape[-1])
    text = getattr(model, "text", None)  # CustomTextCLIP: a text tower module with its own projection
    output_dim = getattr(text, "output_dim", None)
    if isinstance(output_dim, int):
        return output_dim
    return None


class FrozenCLIP(FrozenEncoder):
    """A frozen open_clip model: five image trunk levels and sentence features, cached per instruction.

    ``trunk_channels`` and ``sentence_dim`` are per instance, read from the model's modules:

    - ResNet towers: the stem and layer1..layer4 of ``forward_intermediates`` (strides 4, 4, 8, 16, 32);
      channels = the stem's last conv and each layer's last bottleneck conv (RN50, RN101:
      64, 256, 512, 1024, 2048; RN50x4: 80, 320, 640, 1280, 2560).
    - ViT towers: five levels of the transformer width (768 for ViT-B) built from patch tokens, see
      :func:`~cliport.models.encoders.clip_vit.vit_levels`.

    ``sentence_dim`` is the text projection's output width (RN50: 1024; RN101, ViT-B-16: 512). Images are
    normalised with the model's ``visual.image_mean/image_std``; sentences use the model's own tokenizer and
    context length (:attr:`context_length`).
    """

    model: Any  # an open_clip CLIP model: open_clip ships no type information
    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, model: nn.Module, source: str, model_name: str = MODEL_NAME) -> None:
        """``model``: an open_clip CLIP of ``model_name`` (see :func:`build_clip_model`); ``source``: where its
        weights came from (reported by :meth:`sources`)."""
        super().__init__()
        from open_clip.transformer import VisionTransformer

        self.model = model
        self.source = source
        self.model_name = model_name
        self._tokenizer = load_tokenizer(model_name)
        self.context_length = int(getattr(self._tokenizer, "context_length", None) or self.model.context_length)
        visual = self.model.visual
        self.trunk_channels = _trunk_channels(visual)
        #: 0-based indices of the four blocks the ViT levels come from; None for a ResNet tower.
        self.vit_blocks = (
            vit_block_indices(len(visual.transformer.resblocks)) if isinstance(visual, VisionTransformer) else None
        )
        sentence_dim = _sentence_dim(model)
        if sentence_dim is None:  # not readable from the modules: one tiny pass
            with torch.no_grad():
                sentence_dim = int(self.model.encode_text(self._tokenizer(["a"])).shape[-1])
        self.sentence_dim = sentence_dim
        mean = getattr(visual, "image_mean", None) or CLIP_MEAN
        std = getattr(visual, "image_std", None) or CLIP_STD
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1), persistent=False)
        self.freeze()

    def sources(self) -> dict[str, str]:
        return {"clip_weights": self.source}

    def image_module(self) -> nn.Module:
        return self.model.visual

    def instruction_note(self, text: str) -> str | None:
        n_tokens = count_tokens(self._tokenizer, text)
        if n_tokens > self.context_length:
            return f"the instruction has {n_tokens} CLIP tokens; CLIP reads the first {self.context_length}"
        return None

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        x = ((rgb - self.mean) / self.std).to(self.image_dtype())
        return trunk_levels(self.model.visual, x, self.vit_blocks)

    def dense_embeddings(self, layer4: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return dense_embeddings(self.model.visual, layer4.to(self.image_dtype())).float()

    def logit_scale(self) -> float:
        return float(self.model.logit_scale.exp())

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        return self.model.encode_text(self._tokenizer(texts).to(self.mean.device))


def load_clip(source: str, model_name: str = MODEL_NAME) -> FrozenCLIP:
    """Load frozen open_clip ``model_name`` (default RN50-quickgelu) from ``source``: a pretrained tag of
    the model ("openai" for the default), a weights file, or "random".

    Checks in this order, each failing in one line before the next is tried: the name
    (:class:`UnknownEncoderError`, :class:`UnsupportedEncoderError`), the tokenizer
    (:class:`TokenizerUnavailable`), then the weights (:class:`CLIPWeightsUnavailable`).
    """
    check_model_name(model_name)
    load_tokenizer(model_name)
    return FrozenCLIP(build_clip_model(source, model_name), source, model_name)
