"""Static assets and shared helpers of the packing family: the brown container, the pallet, a k-d split of a
box into cells, and a zone-aware oracle. The named objects of the packing-objects tasks are
:mod:`cliport.tasks.packing_object_set`'s."""

from __future__ import annotations

from typing import Any

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.colors import COLORS

BROWN = COLORS["brown"]
WOOD = (205, 170, 125)
FLOOR_THICKNESS = 0.002
WALL_THICKNESS = 0.005


# ---------------------------------------------------------------------- static assets
def container(env: Any, pose: Pose, interior: tuple[float, float], wall_height: float = 0.03) -> int:
    """A static open brown box: a thin floor and four low walls around an ``interior`` (x, y) area.

    ``pose`` is the centre of the floor's underside; the floor's top is at z = FLOOR_THICKNESS.
    """
    sx, sy = interior
    w = WALL_THICKNESS
    parts: list[dict] = [
        {"type": "box", "size": (sx + 2 * w, sy + 2 * w, FLOOR_THICKNESS), "position": (0, 0, FLOOR_THICKNESS / 2)}
    ]
    for sign in (-1, 1):
        parts.append(
            {"type": "box", "size": (w, sy + 2 * w, wall_height), "position": (sign * (sx + w) / 2, 0, wall_height / 2)}
        )
        parts.append(
            {"type": "box", "size": (sx, w, wall_height), "position": (0, sign * (sy + w) / 2, wall_height / 2)}
        )
    return env.add_object(shapes.compound(env.client, env.asset_dir, parts, pose, color=BROWN, mass=0.0), "fixed")


PALLET_SIZE = (0.3, 0.25)
PALLET_HEIGHT = 0.02


def pallet(env: Any, pose: Pose, size: tuple[float, float] = PALLET_SIZE, height: float = PALLET_HEIGHT) -> int:
    """A static wooden pallet: three stringers along x under five deck slats along y; top at ``height``."""
    sx, sy = size
    deck = 0.005
    parts: list[dict] = []
    for y in (-sy / 2 + 0.015, 0.0, sy / 2 - 0.015):
        parts.append({"type": "box", "size": (sx, 0.03, height - deck), "position": (0, y, (height - deck) / 2)})
    n_slats, gap = 5, 0.0125
    slat = (sx - (n_slats - 1) * gap) / n_slats
    for k in range(n_slats):
        x = -sx / 2 + slat / 2 + k * (slat + gap)
        parts.append({"type": "box", "size": (slat, sy, deck), "position": (x, 0, height - deck / 2)})
    return env.add_object(shapes.compound(env.client, env.asset_dir, parts, pose, color=WOOD, mass=0.0), "fixed")


def kd_split(
    rng: np.random.Generator, size: tuple[float, ...], min_side: float, max_cells: int | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split a box of ``size`` (centred at the origin) into cells by random axis-aligned cuts.

    An axis is cut only when it is longer than 2 * ``min_side``; the cut leaves at least ``min_side``
    on both sides. Returns (centre, size) per cell. With ``max_cells``, the largest cells are split first
    and splitting stops at that many cells.
    """
    cells = [(np.zeros(len(size)), np.asarray(size, dtype=float))]
    while max_cells is None or len(cells) < max_cells:
        splittable = [k for k, (_, s) in enumerate(cells) if np.any(s > 2 * min_side)]
        if not splittable:
            break
        k = max(splittable, key=lambda i: float(np.prod(cells[i][1]))) if max_cells else splittable[0]
        centre, s = cells.pop(k)
        axes = np.nonzero(s > 2 * min_side)[0]
        axis = int(axes[rng.integers(len(axes))])
        cut = float(rng.uniform(min_side, s[axis] - min_side))
        lo = centre - s / 2
        for start, length in ((0.0, cut), (cut, s[axis] - cut)):
            new_size = s.copy()
            new_size[axis] = length
            new_lo = lo.copy()
            new_lo[axis] += start
            cells.insert(k, (new_lo + new_size / 2, new_size))
    return cells


# ---------------------------------------------------------------------- oracle
class ZoneOracleMixin(Task):
    """Oracle for zone-metric steps: an object counts as done once it lies fully inside the zone.

    The base oracle decides "done" with the pose test (within 1 cm of a target), so on a zone step it
    would pick up objects that are already packed but settled slightly off their target. Here done
    objects are those with zone fraction 1; each holds its nearest allowed target; the rest are
    handled farthest-first as in the base oracle.
    """

    def oracle_act(self, obs: dict | None = None) -> dict[str, Any] | None:
        if not self.goals or self.goals[0].metric != "zone":
            return super().oracle_act(obs)
        step = self.goals[0]
        height, ids = self.env.oracle_heightmap()
        done = [self.zone_fraction(step, b) >= 1.0 for b in step.objects]
        taken: set[int] = set()
        if not step.replace:
            for i, body in enumerate(step.objects):
                if done[i]:
                    free = [int(j) for j in np.nonzero(step.matches[i])[0] if int(j) not in taken]
                    if free:
                        taken.add(min(free, key=lambda j: self._xy_distance(body, step, j)))
        candidates = []
        for i, body in enumerate(step.objects):
            if done[i]:
                continue
            free = [int(j) for j in np.nonzero(step.matches[i])[0] if int(j) not in taken]
            if free:
                j = min(free, key=lambda j: self._xy_distance(body, step, j))
                candidates.append((self._xy_distance(body, step, j), i, j))
        for _, i, j in sorted(candidates, reverse=True):
            pick = self.sample_pick(step.objects[i], height, ids)
            if pick is not None:
                return {"pose0": pick, "pose1": self.place_pose(step, i, j, pick)}
        return None

    def _xy_distance(self, body: int, step: GoalStep, j: int) -> float:
        return float(np.linalg.norm(np.subtract(self._pose(body)[0][:2], step.targets[j][0][:2])))
