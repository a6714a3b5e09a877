"""The training objective of every agent, its inputs (a batch as tensors on the device), its optimiser and the
project's one optimiser step."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, TypedDict

import torch
import torch.nn.functional as F

#: ``(pose0, pose1, (H, W)) -> (pick pixels, place pixels, rotation bins)``: an agent's ``action_targets``.
TargetsFn = Callable[[Any, Any, tuple[int, int]], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]
#: ``batch -> (loss, info)``: info is a dict of floats (``compute_loss``) or the (3,) device terms (``_loss_terms``).
LossFn = Callable[[dict[str, Any]], tuple[torch.Tensor, Any]]


class TrainingInputs(TypedDict):
    """A training batch as :meth:`~cliport.agents.base.PickPlaceAgent._loss_terms` takes it (``training_inputs``)."""

    color: torch.Tensor  # (B, H, W, 3) uint8
    height: torch.Tensor  # (B, H, W) float
    pick_pix: torch.Tensor  # (B, 2) int64
    place_pix: torch.Tensor  # (B, 2) int64
    place_rot: torch.Tensor  # (B,) int64
    sentence: torch.Tensor | None  # (B, sentence_dim), or None for agents without language


#: The per-sample cross-entropies a training step reports, in the order of :func:`pick_place_terms`' terms.
TERMS = ("loss", "pick_loss", "place_loss")


def pick_term(
    pick_logits: torch.Tensor, pick_pix: torch.Tensor, loss: str = "sample_ce"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick logits (B, H, W) against target pixels (B, 2) (row, col), int64: the pick's share of the loss to minimise
    and its per-sample cross-entropy (both scalars; see :func:`pick_place_terms`)."""
    w = pick_logits.shape[-1]
    pick_loss = F.cross_entropy(pick_logits.flatten(1).float(), pick_pix[:, 0] * w + pick_pix[:, 1])
    return _minimised(pick_loss, pick_logits, loss), pick_loss


def place_term(
    place_logits: torch.Tensor, place_pix: torch.Tensor, place_rot: torch.Tensor, loss: str = "sample_ce"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Place logits (B, R, H, W) against target pixels (B, 2) and rotation bins (B,), int64: the place's share of
    the loss to minimise and its per-sample cross-entropy (both scalars; see :func:`pick_place_terms`)."""
    h, w = place_logits.shape[-2:]
    place_target = (place_rot * h + place_pix[:, 0]) * w + place_pix[:, 1]
    place_loss = F.cross_entropy(place_logits.flatten(1).float(), place_target)
    return _minimised(place_loss, place_logits, loss), place_loss


def _minimised(cross_entropy: torch.Tensor, logits: torch.Tensor, loss: str) -> torch.Tensor:
    if loss == "cell_mean":
        return cross_entropy / logits[0].numel()
    if loss != "sample_ce":
        raise ValueError(f"unknown loss {loss!r}; choose cell_mean or sample_ce")
    return cross_entropy


def pick_place_terms(
    pick_logits: torch.Tensor,
    place_logits: torch.Tensor,
    pick_pix: torch.Tensor,
    place_pix: torch.Tensor,
    place_rot: torch.Tensor,
    loss: str = "sample_ce",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pick logits (B, H, W) and place logits (B, R, H, W) against target pixels (B, 2) (row, col) and
    rotation bins (B,), int64: the loss to minimise (a scalar) and the per-sample cross-entropies (3,)
    (:data:`TERMS`: ``loss``, ``pick_loss``, ``place_loss``), detached and on the logits' device. Nothing is
    read back to the host, so a training step built on it can be captured as a CUDA graph.

    ``loss``: ``sample_ce``, each map's cross-entropy over all its cells, averaged over the batch (Ravens');
    ``cell_mean``, each map's cross-entropy divided by its cells, H * W for pick and R * H * W for place (the
    reference CLIPort's mean of ``-label * log_softmax`` over the map). The loss is the sum of the two heads'
    shares (:func:`pick_term`, :func:`place_term`), so each head's gradient is that of its own share.
    """
    pick_share, pick_loss = pick_term(pick_logits, pick_pix, loss)
    place_share, place_loss = place_term(place_logits, place_pix, place_rot, loss)
    return pick_share + place_share, join_terms(pick_loss, place_loss)


def join_terms(pick_loss: torch.Tensor, place_loss: torch.Tensor) -> torch.Tensor:
    """The per-sample cross-entropies of the two heads as the (3,) terms of :data:`TERMS`, detached."""
    return torch.stack([pick_loss + place_loss, pick_loss, place_loss]).detach()


def terms_info(terms: torch.Tensor) -> dict[str, float]:
    """The (3,) terms of :func:`pick_place_terms` as ``{"loss": ..., "pick_loss": ..., "place_loss": ...}``
    (read from the device: a synchronisation)."""
    return dict(zip(TERMS, terms.tolist(), strict=True))


def optimizer_step(
    loss_fn: LossFn,
    batch: dict[str, Any],
    optimizer: torch.optim.Optimizer,
    autocast: contextlib.AbstractContextManager[Any] | None = None,
) -> Any:
    """The one training step of the project: zero grads, loss (under ``autocast``), backward, step. Returns
    ``loss_fn``'s info.

    ``loss_fn`` is an agent's ``compute_loss`` or a DDP-wrapped module with the same call signature.
    """
    optimizer.zero_grad(set_to_none=True)
    with autocast or contextlib.nullcontext():
        loss, info = loss_fn(batch)
    loss.backward()
    optimizer.step()
    return info


def make_optimizer(parameters: list[torch.nn.Parameter], lr: float, eps: float, fused: bool) -> torch.optim.Optimizer:
    """Adam over ``parameters`` at learning rate ``lr`` with epsilon ``eps``: the fused kernel where ``fused``, the
    foreach one otherwise. Adam is per parameter, so one optimiser over every net steps as the reference's one
    per net does."""
    return torch.optim.Adam(parameters, lr=lr, eps=eps, fused=fused or None, foreach=None if fused else True)


def batch_tensors(
    batch: dict[str, Any], device: torch.device, targets: TargetsFn
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A training batch's colour (B, H, W, 3) uint8, height (B, H, W), pick and place pixels (B, 2) and rotation
    bins (B,) int64 on ``device``, copied with ``non_blocking=True`` (asynchronous from pinned memory; tensors
    already there are returned as they are). The targets are the batch's ``pick_pix``/``place_pix``/``place_rot``,
    or ``targets`` of its poses ``pose0``/``pose1``."""

    def move(value: Any) -> torch.Tensor:
        return torch.as_tensor(value).to(device, non_blocking=True)

    color, height = move(batch["color"]), move(batch["height"])
    if "pose0" in batch:
        found = targets(batch["pose0"], batch["pose1"], (height.shape[-2], height.shape[-1]))
    else:
        found = (batch["pick_pix"], batch["place_pix"], batch["place_rot"])
    pick_pix, place_pix, place_rot = (move(t).long() for t in found)
    return color, height, pick_pix, place_pix, place_rot
