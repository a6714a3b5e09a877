"""Named colours (RGB 0-255) and the seen/unseen colour splits of CLIPort's language tasks."""

from __future__ import annotations

COLORS: dict[str, tuple[int, int, int]] = {
    "blue": (78, 121, 167),
    "red": (255, 87, 89),
    "green": (89, 169, 79),
    "orange": (242, 142, 43),
    "yellow": (237, 201, 72),
    "purple": (176, 122, 161),
    "pink": (255, 157, 167),
    "cyan": (118, 183, 178),
    "brown": (156, 117, 95),
    "gray": (186, 176, 172),
    "white": (255, 255, 255),
}

TRAIN_COLORS = ["blue", "red", "green", "yellow", "brown", "gray", "cyan"]
EVAL_COLORS = ["blue", "red", "green", "orange", "purple", "pink", "white"]


def split_colors(mode: str, unseen: bool) -> list[str]:
    """Colour names a scene may use: seen colours in train (and everywhere for '-seen-colors'
    variants); unseen colours in val/test of '-unseen-colors' variants."""
    if unseen and mode in ("val", "test"):
        return list(EVAL_COLORS)
    return list(TRAIN_COLORS)
