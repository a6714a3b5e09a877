"""Noticing a net whose output map has gone constant: a training run that can no longer learn.

The key and query nets of two_stream and rn50_bert end in the reference's ``FusionConv``: ReLU over the two
streams' few output channels (3 each), then a 1x1 conv. One large step can leave both streams negative
everywhere; the ReLU then passes zeros, the correlation of key and query is zero at every cell, and no
gradient reaches anything below the ReLU again. The per-sample cross-entropy of a constant map is ln(cells)
whatever the target, so the loss repeats exactly from step to step; a live net's loss never does for long.
"""

from __future__ import annotations

from cliport.errors import UserError

#: Consecutive steps with the same loss (within 1e-6) before a map counts as dead.
PATIENCE = 50
_TOLERANCE = 1e-6


class DeadMapError(UserError, RuntimeError):
    """A net's output map has been constant for :data:`PATIENCE` steps; the message names the net and the step."""


class DeadMapWatch:
    """Follows the per-sample ``pick_loss`` and ``place_loss`` of each step (see :meth:`observe`)."""

    def __init__(self, patience: int = PATIENCE) -> None:
        self.patience = patience
        self._last: dict[str, float] = {}
        self._since: dict[str, int] = {}

    def observe(self, step: int, info: dict[str, float]) -> None:
        """Record one step's losses; raise :class:`DeadMapError` once a map has been constant for ``patience``
        steps."""
        for net in ("pick", "place"):
            value = info.get(f"{net}_loss")
            if value is None:
                continue
            if net in self._last and abs(value - self._last[net]) <= _TOLERANCE:
                self._since.setdefault(net, step - 1)
            else:
                self._since.pop(net, None)
            self._last[net] = value
            first = self._since.get(net)
            if first is not None and step - first >= self.patience:
                raise DeadMapError(
                    f"step {step}: the {net} net's output has been constant since step {first} (its loss is "
                    f"{value:.5f}, the uniform map's, whatever the target): a dead ReLU it cannot recover from. "
                    "Train again with a lower --lr or another --seed (see docs/troubleshooting.md)"
                )
