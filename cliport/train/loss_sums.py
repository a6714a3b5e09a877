"""The training losses of a log window, summed on the device and read once per window.

Reading a loss back to the host every step (``.item()``) makes the host wait for the device at every step;
the trainer adds each step's terms here instead and reads the sums when it writes a row of metrics.csv.
"""

from __future__ import annotations

import torch

from cliport.agents.loss import TERMS


class LossSums:
    """Sums of the per-sample cross-entropies (:data:`~cliport.agents.loss.TERMS`) since the last :meth:`read`,
    in float64 on ``device`` (as exact as the Python floats they replace)."""

    def __init__(self, device: torch.device | str = "cpu") -> None:
        # Updated in place only: a captured training step holds its address.
        self._sums = torch.zeros(len(TERMS), dtype=torch.float64, device=device)
        self.steps = 0

    def add(self, terms: torch.Tensor) -> None:
        """Add one step's (3,) terms (device work only; no synchronisation)."""
        self._sums.add_(terms.to(torch.float64))

    def count(self) -> None:
        """Count one step towards the mean (host side; a captured step adds to the sums by itself)."""
        self.steps += 1

    def read(self) -> dict[str, float]:
        """The mean of each term over the steps counted since the last read (one synchronisation), then start a
        new window."""
        if self.steps == 0:
            raise RuntimeError("no training step was counted since the last read")
        means = {key: value / self.steps for key, value in zip(TERMS, self._sums.tolist(), strict=True)}
        self._sums.zero_()
        self.steps = 0
        return means
