"""packing-boxes: fill a brown container with boxes made by a random k-d split of its interior.

packing-boxes-pairs-{seen,unseen}-colors: the same container, boxes of two named colours fill it, and
four distractor boxes of other colours stay out ("pack all the {c1} and {c2} blocks into the brown box").
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose, at_height, multiply
from cliport.tasks.base import GoalStep
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.packing_assets import FLOOR_THICKNESS, ZoneOracleMixin, container, kd_split
from cliport.tasks.registry import register, register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

MIN_SIDE = 0.05  # smallest box side before the clearance
CLEARANCE = 0.006  # each box is this much smaller than its cell along x and y
BOX_HEIGHT = 0.05
WALL_HEIGHT = 0.03
# packing-boxes-pairs counts only box points below this height above the table: the reference's
# "tight z-bound to discourage stuffing", 5.25 cm above the middle of its 5 cm deep container.
PAIRS_ZONE_TOP = 0.0775


class PackingBoxesBase(ZoneOracleMixin):
    """Shared scene: a container of random interior size split into cells; one box per cell."""

    max_steps = 20
    interior_range = (0.1, 0.3)
    max_boxes = 12

    def build_container(
        self, env: Environment, min_cells: int = 1
    ) -> tuple[Pose, tuple[float, float], list[tuple[Pose, tuple[float, float, float]]]]:
        """Place the container; returns (container pose, interior size, cells as (target pose, box size))."""
        rng = self.rng
        while True:
            interior = (float(rng.uniform(*self.interior_range)), float(rng.uniform(*self.interior_range)))
            cells = kd_split(rng, interior, MIN_SIDE, self.max_boxes)
            if len(cells) >= min_cells:
                break
        pose = self.random_pose((interior[0] + 0.01, interior[1] + 0.01, 0.0), margin=0.01)
        if pose is None:
            raise RuntimeError("no room on the table for the container")
        pose = at_height(pose)
        container(env, pose, interior, WALL_HEIGHT)
        targets = []
        for centre, size in cells:
            local = ((float(centre[0]), float(centre[1]), FLOOR_THICKNESS + BOX_HEIGHT / 2), (0.0, 0.0, 0.0, 1.0))
            box_size = (float(size[0]) - CLEARANCE, float(size[1]) - CLEARANCE, BOX_HEIGHT)
            targets.append((multiply(pose, local), box_size))
        return pose, interior, targets

    def scatter_box(self, env: Environment, size: tuple[float, float, float], color: shapes.Color) -> int | None:
        pose = self.random_pose(size, margin=0.005)
        if pose is None:
            return None
        return env.add_object(shapes.box(env.client, size, pose, color))

    def add_packing_goal(
        self,
        boxes: list[int],
        targets: list[Pose],
        zone_pose: Pose,
        interior: tuple[float, float],
        lang_goal: str | None = None,
        zone_top: float | None = None,
    ) -> None:
        self.add_goal(self.packing_step(boxes, targets, zone_pose, interior, lang_goal, zone_top))

    @staticmethod
    def packing_step(
        boxes: list[int],
        targets: list[Pose],
        zone_pose: Pose,
        interior: tuple[float, float],
        lang_goal: str | None = None,
        zone_top: float | None = None,
    ) -> GoalStep:
        """The goal step of packing ``boxes`` (box i aimed at ``targets[i]``) into the container."""
        return GoalStep(
            objects=boxes,
            matches=np.eye(len(boxes)),
            targets=targets,
            share=1.0,
            symmetries=[math.pi] * len(boxes),
            rotations=True,
            metric="zone",
            zones=[(zone_pose, (interior[0], interior[1], WALL_HEIGHT))],
            zone_top=zone_top,
            lang_goal=lang_goal,
        )


@register("packing-boxes")
class PackingBoxes(PackingBoxesBase):
    lang_template = "pack all the boxes inside the brown box"

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        zone_pose, interior, cells = self.build_container(env)
        colors = [c for c in COLORS if c != "brown"]
        boxes, targets = [], []
        for target, size in cells:
            body = self.scatter_box(env, size, COLORS[colors[int(rng.integers(len(colors)))]])
            if body is not None:
                boxes.append(body)
                targets.append(target)
        self.add_packing_goal(boxes, targets, zone_pose, interior)


class PackingBoxesPairs(PackingBoxesBase):
    """Boxes of two named colours fill the container; four boxes of other colours are distractors.

    A box stacked on another does not count in full (``PAIRS_ZONE_TOP``), as in the reference.
    """

    unseen = False
    lang_template = None
    done_sentence = "done packing blocks."
    n_distractors = 4

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        zone_pose, interior, cells = self.build_container(env, min_cells=2)
        names = [c for c in split_colors(self.mode, self.unseen) if c != "brown"]
        pick = rng.choice(len(names), 2, replace=False)
        pair = [names[int(k)] for k in pick]
        others = [c for c in names if c not in pair]
        boxes, targets = [], []
        self.box_colors: list[tuple[str, int, Pose]] = []  # (colour, body, target of its size) of every box
        for k, (target, size) in enumerate(cells):
            color = pair[k] if k < 2 else pair[int(rng.integers(2))]  # both colours always present
            body = self.scatter_box(env, size, COLORS[color])
            if body is not None:
                boxes.append(body)
                targets.append(target)
                self.box_colors.append((color, body, target))
        for _ in range(self.n_distractors):
            target, size = cells[int(rng.integers(len(cells)))]
            color = others[int(rng.integers(len(others)))]
            body = self.scatter_box(env, size, COLORS[color])
            if body is not None:
                self.box_colors.append((color, body, target))
        self.container = (zone_pose, interior)
        lang = f"pack all the {pair[0]} and {pair[1]} blocks into the brown box"
        self.add_packing_goal(boxes, targets, zone_pose, interior, lang_goal=lang, zone_top=PAIRS_ZONE_TOP)

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """Every pair of the box colours in the scene, in a random order, the boxes of each pair packed (each
        aimed at the cell of its size) before the next pair: the named colours are drawn independently of the
        scene, and distractor boxes take their sizes from the container's cells."""
        colors = sorted({color for color, _, _ in self.box_colors})
        pairs = [(a, b) for i, a in enumerate(colors) for b in colors[i + 1 :]]
        zone_pose, interior = self.container
        plan = []
        for k in rng.permutation(len(pairs)):
            chosen = [(body, target) for color, body, target in self.box_colors if color in pairs[int(k)]]
            boxes, targets = [body for body, _ in chosen], [target for _, target in chosen]
            plan.append(self.packing_step(boxes, targets, zone_pose, interior, zone_top=PAIRS_ZONE_TOP))
        return plan


PackingBoxesPairsSeenColors, PackingBoxesPairsUnseenColors = register_splits(
    PackingBoxesPairs, "packing-boxes-pairs-seen-colors", "packing-boxes-pairs-unseen-colors"
)
