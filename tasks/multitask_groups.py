"""Multi-task groups by name, usable wherever a task name is (datasets, training, demos, evaluation)."""

from __future__ import annotations

from cliport.tasks.registry import register_group

RAVENS = [
    "align-box-corner",
    "assembling-kits",
    "block-insertion",
    "manipulating-rope",
    "packing-boxes",
    "palletizing-boxes",
    "place-red-in-green",
    "stack-block-pyramid",
    "sweeping-piles",
    "towers-of-hanoi",
]

_COLOR_TASKS = [
    "assembling-kits-seq",
    "packing-boxes-pairs",
    "put-block-in-bowl",
    "separating-piles",
    "stack-block-pyramid-seq",
    "towers-of-hanoi-seq",
]
_SHARED = ["align-rope", "packing-shapes"]

SEEN = sorted(
    [f"{t}-seen-colors" for t in _COLOR_TASKS] + _SHARED + ["packing-seen-objects-seq", "packing-seen-objects-group"]
)
UNSEEN = sorted(
    [f"{t}-unseen-colors" for t in _COLOR_TASKS]
    + _SHARED
    + ["packing-unseen-objects-seq", "packing-unseen-objects-group"]
)

# CLIPort's multi-task training set: every language task (their train splits use seen attributes only).
register_group("multi-language-conditioned", sorted(set(SEEN) | set(UNSEEN)))
register_group("multi-language-conditioned-seen", SEEN)
register_group("multi-language-conditioned-unseen", UNSEEN)
register_group("multi-ravens", RAVENS)
