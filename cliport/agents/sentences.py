"""Sentence features as an agent's nets read them: the frozen encoder's features of each instruction, centred
on the training set's instructions where the agent's config asks for it (``center_sentences``).

Centring subtracts the mean of the training set's distinct instructions' features and rescales by their RMS norm
over their centred RMS norm, so that what the instructions share does not drown what tells them apart. The two
numbers live in the agent's ``sentence_mean`` and ``sentence_scale`` buffers (saved with its weights); they are
fitted once, when training starts (:func:`fit_centering`).

With ``gate_phrase_dropout`` the features are of the instructions as the gates read them (:func:`gate_texts`).

An agent with ``similarity_maps`` appends, after them, the unit text embeddings its nets compare with the image's
dense embeddings (:func:`similarity_texts`): the instruction's and its phrases', never centred.
"""

from __future__ import annotations

import torch

from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.dense_clip import (
    SIMILARITY_MAPS,
    PhraseBank,
    instruction_phrases,
    without_describing_words,
)


def check_instructions(agent_name: str, lang: list[str] | None) -> list[str]:
    """``lang`` as a list; ValueError unless every observation has an instruction."""
    if lang is None or any(text is None for text in lang):
        raise ValueError(f"the {agent_name} agent needs an instruction for every observation")
    return list(lang)


def centred(features: torch.Tensor, mean: torch.Tensor, scale: torch.Tensor, fitted: bool) -> torch.Tensor:
    """Sentence features (B, sentence_dim) centred on ``mean`` and scaled by ``scale``; RuntimeError if the two
    were never fitted."""
    if not fitted:
        raise RuntimeError(
            "this agent centres its sentence features but they were never fitted: call "
            "fit_sentence_centering(the training instructions) first (cliport-train does)"
        )
    return (features - mean) * scale


def fit_centering(
    encoder: FrozenEncoder, instructions: list[str], mean: torch.Tensor, scale: torch.Tensor
) -> dict[str, float]:
    """Fit the centring to ``instructions`` (the training set's) into the buffers ``mean`` (sentence_dim,) and
    ``scale`` (a scalar): the mean of their distinct strings' features, and the scale that keeps their RMS norm.
    Returns how many distinct instructions it used and the scale. ValueError for fewer than two distinct
    instructions, or features that are all the same."""
    texts = sorted({text for text in instructions if text})
    if len(texts) < 2:
        raise ValueError(f"centring sentence features needs at least two distinct instructions, got {texts}")
    with torch.no_grad():
        features = encoder.sentence_features(texts)
        feature_mean = features.mean(0)
        spread = (features - feature_mean).pow(2).sum(1).mean().sqrt()
        if not spread > 0:
            raise ValueError("the instructions' sentence features are all the same: nothing to centre")
        mean.copy_(feature_mean)
        scale.copy_(features.pow(2).sum(1).mean().sqrt() / spread)
    return {"instructions": len(texts), "scale": float(scale)}


def act_instructions(instructions: list[str | None]) -> list[str] | None:
    """The instructions of an act batch: all given, or None when none is; ValueError for a mix."""
    if all(i is None for i in instructions):
        return None
    texts = [i for i in instructions if i is not None]
    if len(texts) != len(instructions):
        raise ValueError("an act batch mixes instructions with None: give every observation one, or none")
    return texts


def similarity_texts(encoder: FrozenEncoder, texts: list[str]) -> torch.Tensor:
    """(B,) instructions -> (B, SIMILARITY_MAPS * sentence_dim): per instruction, the unit-norm text embeddings of
    the instruction and of its phrases (:func:`~cliport.models.encoders.dense_clip.instruction_phrases`), zeros
    for a phrase it does not have."""
    rows = []
    for text in texts:
        named = [text, *instruction_phrases(text)]
        features = torch.nn.functional.normalize(encoder.sentence_features(named), dim=1)
        missing = SIMILARITY_MAPS - len(named)
        rows.append(torch.cat([features.flatten(), features.new_zeros(missing * encoder.sentence_dim)]))
    return torch.stack(rows)


def gate_texts(
    encoder: FrozenEncoder, texts: list[str], rate: float, bank: PhraseBank | None, training: bool
) -> list[str]:
    """The instructions as the gates of an agent with ``gate_phrase_dropout`` read them: in training each phrase's
    describing words dropped with probability ``rate`` (torch's generator), at act time those of every phrase the
    phrase bank was not fitted on; with ``rate`` 0, the instructions as given."""
    if not rate:
        return texts
    if bank is None:
        raise RuntimeError("gate_phrase_dropout reads the phrase bank, and this agent has none")
    out = []
    for text in texts:
        phrases = instruction_phrases(text)
        if training:
            drop = (torch.rand(len(phrases)) < rate).tolist()
        else:
            drop = [not held for held in bank.holds(encoder, phrases)]
        out.append(without_describing_words(text, drop))
    return out
