"""CLIP's symmetric contrastive loss (InfoNCE over a batch's image-caption similarities, learnable temperature), with
every caption of the batch that is true of an image counted as one of its positives.

CLIP pairs each image with its own caption and treats the batch's other captions as negatives. Rendered scenes
have a small vocabulary, so a batch of 128 crops holds many true duplicates ("a red block" for two red blocks);
counting them as negatives would push apart what should be together. Here each image's target is spread evenly
over the captions true of it (``positives``), and each caption's over the images it is true of. With exactly one
true caption per image (the identity matrix) this is CLIP's loss.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

#: CLIP clamps its learnable inverse temperature (``logit_scale``, a log) at log(100).
MAX_LOGIT_SCALE = math.log(100.0)


def contrastive_loss(
    image_features: torch.Tensor, text_features: torch.Tensor, logit_scale: torch.Tensor, positives: torch.Tensor
) -> torch.Tensor:
    """The mean of the image-to-text and text-to-image cross-entropies of the scaled cosine similarities.

    ``image_features`` (B, D) and ``text_features`` (B, D), L2-normalised, caption j written for image j;
    ``logit_scale`` () the log of the inverse temperature; ``positives`` (B, B) bool, [i, j] true when caption j is
    true of image i (its diagonal must be true). Returns a scalar.
    """
    if not bool(positives.diagonal().all()):
        raise ValueError("every image's own caption must be among its positives")
    logits = logit_scale.exp() * image_features @ text_features.T  # (B, B): image i, caption j
    targets = positives.float()
    image_to_text = -(targets / targets.sum(1, keepdim=True) * F.log_softmax(logits, dim=1)).sum(1).mean()
    text_to_image = -(targets / targets.sum(0, keepdim=True) * F.log_softmax(logits, dim=0)).sum(0).mean()
    return (image_to_text + text_to_image) / 2


def retrieval_accuracy(image_features: torch.Tensor, text_features: torch.Tensor, positives: torch.Tensor) -> float:
    """The fraction of images whose most similar caption of the batch is true of them: (B, D), (B, D), (B, B) ->
    a float."""
    best = (image_features @ text_features.T).argmax(dim=1)
    return float(positives[torch.arange(len(best)), best].float().mean())
