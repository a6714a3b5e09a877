"""Noticing a net whose output map has gone constant: a training run that can no longer learn.

The key and query nets of two_stream and rn50_bert end in the reference's ``FusionConv``: ReLU over the two
streams' few output channels (3 each), then a 1x1 conv. One large step can leave both streams negative
everywhere; the ReLU then passes zeros, the correlation of key and query is zero at every cell, and no
gradient reaches anything below the ReLU again. The per-sample cross-entropy of a constant map is ln(cells)
whatever the target, so the loss repeats exactly from step to step; a live net's loss never does for long.

The watch follows every step on the losses' device (no per-step read back to the host, so it runs inside a
captured training step) and is read when the trainer logs: a dead map is reported with the step it was seen
at, up to ``log_every`` steps after it happened.
"""

from __future__ import annotations

import torch

from cliport.errors import UserError

#: Consecutive steps with the same loss (within 1e-6) before a map counts as dead.
PATIENCE = 50
_TOLERANCE = 1e-6
_NETS = ("pick", "place")


class DeadMapError(UserError, RuntimeError):
    """A net's output map has been constant for :data:`PATIENCE` steps; the message names the net and the step."""


class DeadMapWatch:
    """Follows the per-sample ``pick_loss`` and ``place_loss`` of each step (see :meth:`observe`) on ``device``;
    :meth:`check` reads what it saw. ``start_step`` is the step before the first observed one (a resumed run's)."""

    def __init__(self, patience: int = PATIENCE, device: torch.device | str = "cpu", start_step: int = 0) -> None:
        self.patience = patience
        self.start_step = start_step
        # Every tensor is updated in place: a captured training step holds their addresses.
        self._steps = torch.zeros((), dtype=torch.int64, device=device)
        self._last = torch.full((2,), float("nan"), dtype=torch.float64, device=device)
        self._run = torch.zeros(2, dtype=torch.int64, device=device)  # steps equal to their previous one
        self._dead = torch.zeros(2, dtype=torch.bool, device=device)
        self._dead_at = torch.zeros(2, dtype=torch.int64, device=device)  # observed steps when first found dead
        self._dead_value = torch.zeros(2, dtype=torch.float64, device=device)

    def observe(self, terms: torch.Tensor) -> None:
        """Record one step's losses, the (3,) terms ``loss``, ``pick_loss``, ``place_loss``
        (:func:`~cliport.agents.loss.pick_place_terms`), on their device without reading them."""
        values = terms[1:].to(torch.float64)
        self._steps.add_(1)
        # The difference of two float32 losses is exact in float64, as it was in Python floats.
        same = (values - self._last).abs() <= _TOLERANCE
        self._run.copy_(torch.where(same, self._run + 1, torch.zeros_like(self._run)))
        self._last.copy_(values)
        found = (self._run >= self.patience) & ~self._dead
        self._dead_at.copy_(torch.where(found, self._steps, self._dead_at))
        self._dead_value.copy_(torch.where(found, values, self._dead_value))
        self._dead.logical_or_(found)

    def check(self) -> None:
        """Raise :class:`DeadMapError` if a map has been constant for ``patience`` steps at any step observed
        so far (reads the device: a synchronisation)."""
        dead = self._dead.tolist()
        if not any(dead):
            return
        at, values = self._dead_at.tolist(), self._dead_value.tolist()
        # The net found first (pick on a tie, as the per-step check named it).
        net = min((i for i in range(len(_NETS)) if dead[i]), key=lambda i: at[i])
        step = self.start_step + at[net]
        raise DeadMapError(
            f"step {step}: the {_NETS[net]} net's output has been constant since step {step - self.patience} (its "
            f"loss is {values[net]:.5f}, the uniform map's, whatever the target): a dead ReLU it cannot recover "
            "from. Train again with a lower --lr or another --seed (see docs/troubleshooting.md)"
        )
