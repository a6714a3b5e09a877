"""The contrastive loss is CLIP's when each image has one true caption, and counts every true caption otherwise."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from cliport.pretrain.loss import contrastive_loss, retrieval_accuracy


def _features(n: int, d: int = 8, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return F.normalize(torch.randn(n, d, generator=g), dim=1), F.normalize(torch.randn(n, d, generator=g), dim=1)


def test_identity_positives_give_clips_loss() -> None:
    images, texts = _features(6)
    scale = torch.tensor(math.log(10.0))
    logits = 10.0 * images @ texts.T
    clip = (F.cross_entropy(logits, torch.arange(6)) + F.cross_entropy(logits.T, torch.arange(6))) / 2
    ours = contrastive_loss(images, texts, scale, torch.eye(6, dtype=torch.bool))
    assert torch.allclose(ours, clip, atol=1e-6)


def test_duplicate_captions_are_not_pushed_apart() -> None:
    """Two images of red blocks under two copies of "a red block": with both copies marked true, features that match
    them as they are reach the loss's lower bound (the entropy of the targets, log 2 for each duplicated row), so
    nothing pulls the copies apart; other features only cost more."""
    images = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    positives = torch.tensor([[1, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=torch.bool)
    scale = torch.tensor(math.log(100.0))
    bound = 2 * math.log(2) / 3  # per direction: rows of 2, 2 and 1 true captions
    assert contrastive_loss(images, images.clone(), scale, positives).item() == pytest.approx(bound, abs=1e-6)
    for seed in range(5):
        texts = F.normalize(images + 0.3 * torch.randn(3, 2, generator=torch.Generator().manual_seed(seed)), dim=1)
        assert contrastive_loss(images, texts, scale, positives).item() > bound
    assert retrieval_accuracy(images, images, positives) == 1.0


def test_temperature_is_learned_and_own_caption_required() -> None:
    images, texts = _features(4)
    scale = torch.tensor(math.log(1 / 0.07), requires_grad=True)
    contrastive_loss(images, texts, scale, torch.eye(4, dtype=torch.bool)).backward()
    assert scale.grad is not None and scale.grad != 0
    with pytest.raises(ValueError, match="own caption"):
        contrastive_loss(images, texts, scale, torch.zeros(4, 4, dtype=torch.bool))
