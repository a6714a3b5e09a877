"""The seed protocol: train seeds are even from 0, val seeds odd from 1, test seeds odd from 10001."""

from __future__ import annotations

_FIRST = {"train": 0, "val": 1, "test": 10001}
MODES = tuple(_FIRST)


def episode_seeds(mode: str, n: int, start_index: int = 0) -> list[int]:
    """The seeds of episodes ``start_index .. start_index + n - 1`` of a split."""
    if mode not in _FIRST:
        raise ValueError(f"mode must be 'train', 'val' or 'test', got {mode!r}")
    return [_FIRST[mode] + 2 * i for i in range(start_index, start_index + n)]


def seed_mode(seed: int) -> str:
    """The split a seed belongs to in the seed protocol (the reference's and ours)."""
    if seed % 2 == 0:
        return "train"
    return "test" if seed >= _FIRST["test"] else "val"
