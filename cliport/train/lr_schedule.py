"""The learning rate over a run: constant, then a linear cooldown to zero over the run's last fraction.

How far a run has got is the larger of its steps over ``n_steps`` and, with a time budget, its seconds of training
over the budget, so a run that stops on its time budget cools down at the end of the time it has, whatever the
machine's speed. Training to a time budget makes the learning rate of each step depend on that speed, as its step
count already does; a run to ``n_steps`` alone is a function of its step.
"""

from __future__ import annotations

import torch


def cooldown_factor(progress: float, cooldown: float) -> float:
    """The learning rate's multiplier at ``progress`` (0: the start, 1: the end) of a run whose last ``cooldown``
    fraction falls linearly to zero (0: constant)."""
    if cooldown <= 0:
        return 1.0
    return min(1.0, max(0.0, (1.0 - progress) / cooldown))


class LrCooldown:
    """Sets ``optimizer``'s learning rates to their values at construction times :func:`cooldown_factor`."""

    def __init__(self, optimizer: torch.optim.Optimizer, cooldown: float) -> None:
        self.optimizer = optimizer
        self.cooldown = cooldown
        self.base = [float(group["lr"]) for group in optimizer.param_groups]

    def apply(self, progress: float) -> float:
        """Set the rates for a step taken at ``progress``; returns the multiplier. Without a cooldown the rates are
        left as they are (a resumed run keeps the rates its optimiser state holds, as before cooldowns existed)."""
        if self.cooldown <= 0:
            return 1.0
        factor = cooldown_factor(progress, self.cooldown)
        for group, base in zip(self.optimizer.param_groups, self.base, strict=True):
            group["lr"] = base * factor
        return factor
