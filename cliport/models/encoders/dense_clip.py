"""Text-aligned features at every position of a frozen open_clip image tower, and their similarity to a sentence.

CLIP aligns text with one pooled embedding per image. The last trunk level already holds, at each position, what
that pooling averages (MaskCLIP, Zhou et al. 2022): a ModifiedResNet's attention pool is a softmax-weighted sum of
``c_proj(v_proj(x_j + pos_j))`` over the positions j (per head), so those vectors, taken one position at a time,
live in the space the text embedding lives in. :func:`dense_embeddings` computes them from the trunk's layer4 (the
positional embedding resized to the map); for a ViT tower, the analogue is the final norm and projection applied
to every patch token of the last level. :func:`similarity_map` is their cosine similarity with text embeddings.

A two-stream net with ``similarity_maps`` reads :data:`SIMILARITY_MAPS` such maps as extra lateral channels: the
instruction's, and those of its first two phrases (:func:`instruction_phrases`: "the pink block", "the red bowl"),
so that what the net learns to do with a map ("pick where the first phrase is") holds for words its demos never
showed, as far as the encoder's map finds them.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

#: The maps a net with ``similarity_maps`` reads: the whole instruction's and its first two phrases'.
SIMILARITY_MAPS = 3
_ARTICLES = frozenset({"the", "a", "an"})
_BREAKS = frozenset(
    {"in", "on", "into", "onto", "to", "of", "from", "with", "and", "at", "inside", "under", "above", "beside", "by",
     "near", "next", "left", "right", "front", "behind", "then"}
)  # fmt: skip


def instruction_phrases(text: str, n: int = SIMILARITY_MAPS - 1) -> list[str]:
    """The first ``n`` phrases of an instruction, each from an article to the next preposition, article or end:
    "put the pink block in the red bowl" -> ["the pink block", "the red bowl"]; fewer where it has fewer."""
    words, spans = _phrase_spans(text)
    return [" ".join(words[start:end]) for start, end in spans][:n]


def without_describing_words(text: str, drop: list[bool]) -> str:
    """The instruction with the phrases flagged in ``drop`` (in :func:`instruction_phrases`' order) cut to their
    article and last word: "put the pink block in the red bowl", [True, False] -> "put the block in the red
    bowl" (lower case, without commas and full stops, where any phrase is cut; else the instruction as given)."""
    words, spans = _phrase_spans(text)
    cut = [span for span, flag in zip(spans, drop, strict=False) if flag and span[1] - span[0] > 2]
    if not cut:
        return text
    for start, end in reversed(cut):
        words[start + 1 : end - 1] = []
    return " ".join(words)


def _phrase_spans(text: str) -> tuple[list[str], list[tuple[int, int]]]:
    """The instruction's words (lower case, commas and full stops dropped) and its phrases' [start, end) spans:
    each from an article to the next preposition, article or end, of two words or more."""
    words = text.lower().replace(",", " ").replace(".", " ").split()
    spans: list[tuple[int, int]] = []
    start: int | None = None
    for i, word in enumerate(words):
        if word in _ARTICLES:
            if start is not None:
                spans.append((start, i))
            start = i
        elif start is not None and word in _BREAKS:
            spans.append((start, i))
            start = None
    if start is not None:
        spans.append((start, len(words)))
    return words, [(s, e) for s, e in spans if e - s > 1]


def _resized_grid(pos: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """An attention pool's positional embedding of its grid (S*S, C) as a (1, C, h, w) map resized to ``size``."""
    grid = round(pos.shape[0] ** 0.5)
    if grid * grid != pos.shape[0]:
        raise ValueError(f"the attention pool's {pos.shape[0]} positions are not a square grid")
    pos = pos.T.reshape(1, -1, grid, grid)
    if (grid, grid) == tuple(size):
        return pos
    return F.interpolate(pos.float(), size=size, mode="bicubic", align_corners=False).to(pos.dtype)


def dense_embeddings(visual: Any, layer4: torch.Tensor) -> torch.Tensor:
    """The open_clip image tower ``visual`` (a ModifiedResNet or a VisionTransformer) and its last trunk level
    (N, C, h, w) -> (N, E, h, w): at each position, the image embedding space's vector (E: the tower's
    ``output_dim``, that of the text embedding).

    ModifiedResNet: ``c_proj(v_proj(x + pos))`` of its attention pool, ``pos`` resized bicubically to (h, w).
    VisionTransformer: ``ln_post(x) @ proj`` of each token of the level."""
    n, c, h, w = layer4.shape
    tokens = layer4.flatten(2).transpose(1, 2)  # (N, hw, C)
    pool = getattr(visual, "attnpool", None)
    if pool is not None:
        pos = _resized_grid(pool.positional_embedding[1:], (h, w)).flatten(2).transpose(1, 2)
        out = F.linear(F.linear(tokens + pos.to(tokens.dtype), pool.v_proj.weight, pool.v_proj.bias),
                       pool.c_proj.weight, pool.c_proj.bias)  # fmt: skip
    elif getattr(visual, "proj", None) is not None and hasattr(visual, "ln_post"):
        out = visual.ln_post(tokens) @ visual.proj
    else:
        raise ValueError(f"no dense embeddings for an image tower of type {type(visual).__name__}")
    return out.transpose(1, 2).reshape(n, -1, h, w)


def similarity_map(dense: torch.Tensor, texts: torch.Tensor) -> torch.Tensor:
    """Dense embeddings (N, E, h, w) and K text embeddings per sample (N, K, E) -> their cosine similarity
    (N, K, h, w); a zero text embedding gives a zero map."""
    if dense.shape[0] != texts.shape[0] or dense.shape[1] != texts.shape[2]:
        raise ValueError(f"dense embeddings {tuple(dense.shape)} and texts {tuple(texts.shape)} differ in N or E")
    return torch.einsum("nehw,nke->nkhw", F.normalize(dense, dim=1), F.normalize(texts, dim=2))


def bank_probability(
    dense: torch.Tensor, texts: torch.Tensor, bank: torch.Tensor, valid: torch.Tensor, logit_scale: float
) -> torch.Tensor:
    """Per position, the probability that each text, rather than any entry of a bank, describes it best:
    dense embeddings (N, E, h, w), K texts per sample (N, K, E), a bank (P, E) and which of its rows are
    entries (P,) bool -> (N, K, h, w): a softmax at CLIP's inverse temperature ``logit_scale`` over the text
    and the bank's entries other than the text itself (cosine above 1 - 1e-4). A zero text gives a zero map."""
    if dense.shape[1] != bank.shape[1]:
        raise ValueError(f"dense embeddings {tuple(dense.shape)} and the bank {tuple(bank.shape)} differ in E")
    own = logit_scale * similarity_map(dense, texts)  # (N, K, h, w)
    others = logit_scale * torch.einsum("nehw,pe->nphw", F.normalize(dense, dim=1), F.normalize(bank, dim=1))
    units = F.normalize(texts, dim=2)
    same = torch.einsum("nke,pe->nkp", units, F.normalize(bank, dim=1)) > 1 - 1e-4  # (N, K, P)
    left_out = same | ~valid  # (N, K, P)
    others = others[:, None].masked_fill(left_out[..., None, None], float("-inf"))  # (N, K, P, h, w)
    everything = torch.cat([own[:, :, None], others], dim=2)
    probability = (own - torch.logsumexp(everything, dim=2)).exp()
    return probability * (texts.norm(dim=2) > 0)[..., None, None]


class PhraseBank(nn.Module):
    """The texts a similarity map's text competes with in :func:`bank_probability`: the unit text embeddings of
    the training instructions' phrases, up to :attr:`CAPACITY`, fitted once when training starts
    (:meth:`fit`) and saved with the weights (buffers ``embeddings`` (CAPACITY, E) and ``valid`` (CAPACITY,))."""

    CAPACITY = 256
    embeddings: torch.Tensor
    valid: torch.Tensor

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("embeddings", torch.zeros(self.CAPACITY, dim))
        self.register_buffer("valid", torch.zeros(self.CAPACITY, dtype=torch.bool))
        self.fitted = False  # read without a device sync

    def fit(self, encoder: Any, instructions: list[str]) -> int:
        """Fill the bank with ``encoder``'s text embeddings of the phrases of ``instructions`` (the training set's;
        not the instructions themselves, which would compete with their own phrases); returns how many it holds.
        ValueError for none, or more than :attr:`CAPACITY`."""
        texts = sorted({phrase for text in instructions if text for phrase in instruction_phrases(text)})
        if not texts or len(texts) > self.CAPACITY:
            raise ValueError(
                f"a phrase bank holds 1 to {self.CAPACITY} phrases, got {len(texts)} from the instructions"
            )
        with torch.no_grad():
            self.embeddings.zero_()
            self.embeddings[: len(texts)] = F.normalize(encoder.sentence_features(texts), dim=1)
            self.valid.zero_()
            self.valid[: len(texts)] = True
        self.fitted = True
        return len(texts)

    def holds(self, encoder: Any, phrases: list[str]) -> list[bool]:
        """Whether each phrase is one the bank was fitted on (its text embedding is one of the bank's)."""
        if not phrases:
            return []
        with torch.no_grad():
            texts = F.normalize(encoder.sentence_features(phrases), dim=1).to(self.embeddings)
            cosines = texts @ self.embeddings[self.valid].T
        return [bool(c) for c in (cosines.max(dim=1).values > 1 - 1e-4).tolist()]

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):  # type: ignore[no-untyped-def]  # torch's hook
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self.fitted = bool(self.valid.any())

    def forward(self, dense: torch.Tensor, texts: torch.Tensor, logit_scale: float) -> torch.Tensor:
        """Dense embeddings (N, E, h, w) and texts (N, K, E) -> each text's bank probability (N, K, h, w)."""
        return bank_probability(dense, texts, self.embeddings, self.valid, logit_scale)
