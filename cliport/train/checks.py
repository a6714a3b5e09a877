"""Checks of the training agent itself while it trains, and the curve they draw (``RUN/held_out.json``).

A check (:class:`AgentCheck`; the language lesson's is :class:`cliport.evaluation.held_out.HeldOutCheck`) scores
the live agent at the steps it asks for and at the run's last step, without reading a checkpoint back. The
trainer keeps a scheduled checkpoint of the best-scoring step (ties: the later step) and removes the one it
replaces; :class:`CheckCurve` holds the scores, rewritten atomically after every check. A resumed run drops the
checks of steps after the one it resumes from (their checkpoints came from steps it will train again) and
checks those steps again when it gets there.
"""

from __future__ import annotations

import os
import time
from typing import Any, Protocol

from cliport.utils.files import read_json, write_json


class AgentCheck(Protocol):
    """Scores the training agent at steps of its choosing (and at the last step); ``score`` is maximised."""

    def due(self, step: int) -> bool:
        """Whether to check after ``step`` steps."""

    def check(self, step: int, agent: Any) -> dict[str, Any]:
        """Score the agent as it is after ``step`` steps: a row of numbers with a ``score`` (higher is better).
        The agent may be left in eval mode."""

    def describe(self) -> dict[str, Any]:
        """What the curve's file records about the check (its scenes, schedule)."""


class CheckCurve:
    """The checks of one run: ``path`` (RUN/held_out.json) holds ``check`` (what was checked), ``curve`` (one row
    per check: step, the check's numbers, seconds it took) and ``best_step`` / ``best_score``."""

    def __init__(self, path: str, description: dict[str, Any], resumed_step: int) -> None:
        self.path = path
        self.description = description
        self.rows: list[dict[str, Any]] = []
        if os.path.exists(path):
            self.rows = [row for row in read_json(path).get("curve", []) if row["step"] <= resumed_step]

    @property
    def best(self) -> dict[str, Any] | None:
        """The row with the highest score (the later of equal ones), or None before any check."""
        return max(self.rows, key=lambda row: (row["score"], row["step"]), default=None)

    def has(self, step: int) -> bool:
        return any(row["step"] == step for row in self.rows)

    def run(self, check: AgentCheck, step: int, agent: Any) -> tuple[dict[str, Any], bool]:
        """Check the agent after ``step`` steps and record it; returns the row and whether it is the new best."""
        start = time.perf_counter()
        row = {"step": step, **check.check(step, agent), "seconds": 0.0}
        row["seconds"] = round(time.perf_counter() - start, 2)
        self.rows = [r for r in self.rows if r["step"] != step] + [row]
        self.write()
        return row, self.best is row

    def write(self) -> None:
        best = self.best
        data: dict[str, Any] = {"check": self.description, "curve": self.rows}
        if best is not None:
            data.update(best_step=best["step"], best_score=best["score"])
        write_json(self.path, data)


def check_line(row: dict[str, Any], best: bool) -> str:
    """The line a check prints: its step, its numbers, the seconds it took and whether it is the best so far."""
    numbers = ", ".join(f"{k} {v}" for k, v in row.items() if k not in ("step", "score", "seconds"))
    return f"check at step {row['step']}: {numbers} ({row['seconds']:.0f} s){'; the best so far' if best else ''}"
