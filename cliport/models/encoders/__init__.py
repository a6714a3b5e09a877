"""The frozen pretrained encoders of the semantic streams, and loading their weights.

Each encoder is a :class:`FrozenEncoder` (``base``): a multi-scale image trunk and a sentence encoder whose
weights never train, shared by an agent's nets, which are built from its channel counts. Here are the encoders
and everything that gets their weights:

===================== ====================================================================================
module                holds
===================== ====================================================================================
base                  :class:`FrozenEncoder`, the base every encoder subclasses (trunk strides, caching)
clip_encoder          ``FrozenCLIP`` and ``load_clip``: any open_clip model with a trunk adapter
clip_registry         open_clip model names, checked before anything is built; open_clip's log kept quiet
clip_weights          CLIP's weights: published (Hugging Face cache or network), a file, or seeded random
clip_tokenizer        CLIP's tokenizer, offline where it can be, and instruction token counts
clip_vit              the ViT adapter: five trunk levels from a vision transformer's blocks
rn50_bert_encoder     ``FrozenRN50BERT`` and ``load_rn50_bert``: the RN50-BERT ablation's two frozen parts
rn50_trunk            torchvision's ResNet-50 as a five-level trunk, and its ImageNet weights
distilbert            DistilBERT and its tokenizer from a folder, the Hugging Face cache, or random
weights               what the loaders share: state-dict files, architecture checks, batch-norm calibration
===================== ====================================================================================

Whether the Hugging Face Hub may be contacted (``HF_HUB_OFFLINE``) is :mod:`cliport.utils.hub`'s; what to do
offline is docs/weights-offline.md. Nothing here imports a net: the nets read an encoder through
:class:`~cliport.models.encoder_net.EncoderNet`.
"""

from cliport.models.encoders.base import TRUNK_STRIDES, FrozenEncoder

__all__ = ["TRUNK_STRIDES", "FrozenEncoder"]
