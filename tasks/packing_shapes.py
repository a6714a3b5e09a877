"""packing-shapes: pack the named kit shape into the brown box, among four distractor shapes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.kit_shapes import SHAPES, ShapeTask, split_shapes
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_OBJECTS = 5
WALL_HEIGHT = 0.05
WALL_THICKNESS = 0.006
FLOOR_THICKNESS = 0.002


def container_parts(inner: tuple[float, float]) -> list[dict]:
    """Floor and four walls of an open box with the given inner size, origin at the floor's centre bottom."""
    sx, sy = inner
    t, h = WALL_THICKNESS, WALL_HEIGHT
    return [
        {"type": "box", "size": (sx + 2 * t, sy + 2 * t, FLOOR_THICKNESS), "position": (0, 0, FLOOR_THICKNESS / 2)},
        {"type": "box", "size": (t, sy + 2 * t, h), "position": ((sx + t) / 2, 0, h / 2)},
        {"type": "box", "size": (t, sy + 2 * t, h), "position": (-(sx + t) / 2, 0, h / 2)},
        {"type": "box", "size": (sx, t, h), "position": (0, (sy + t) / 2, h / 2)},
        {"type": "box", "size": (sx, t, h), "position": (0, -(sy + t) / 2, h / 2)},
    ]


@register("packing-shapes")
class PackingShapes(ShapeTask):
    max_steps = 1
    template = "pack the {shape} in the brown box"
    done_sentence = "done packing shapes."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        shape_ids = [int(s) for s in rng.choice(split_shapes(self.mode), N_OBJECTS, replace=False)]
        colors = [str(c) for c in rng.permutation(split_colors(self.mode, unseen=True))[:N_OBJECTS]]
        inner = (float(rng.uniform(0.1, 0.15)), float(rng.uniform(0.1, 0.15)))
        outer = (inner[0] + 2 * WALL_THICKNESS, inner[1] + 2 * WALL_THICKNESS, WALL_HEIGHT)
        zone_pose = self.random_pose(outer)
        if zone_pose is None:
            raise RuntimeError("no room on the table for the box")
        zone_pose = at_height(zone_pose)
        box = shapes.compound(env.client, env.asset_dir, container_parts(inner), zone_pose, color=COLORS["brown"])
        env.add_object(box, "fixed")
        objects = self.add_shapes(shape_ids, colors)
        self.box = (zone_pose, inner)
        self.add_goal(self.pack_step(objects[0], self.template.format(shape=SHAPES[shape_ids[0]].label)))

    def pack_step(self, body: int, lang_goal: str | None = None) -> GoalStep:
        """The goal step of packing the shape ``body`` into the box (after ``reset``)."""
        zone_pose, inner = self.box
        return GoalStep(
            objects=[body],
            matches=np.ones((1, 1)),
            targets=[zone_pose],
            share=1.0,
            symmetries=[SHAPES[self.object_shapes[body]].symmetry],
            rotations=True,
            metric="zone",
            zones=[(zone_pose, (inner[0], inner[1], WALL_HEIGHT))],
            lang_goal=lang_goal,
        )

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """The five shapes in a random order: the named one is the first drawn of five distinct shapes in
        random colours at random places, so nothing in the scene tells it apart (one action is allowed)."""
        bodies = list(self.object_shapes)
        return [self.pack_step(bodies[int(k)]) for k in rng.permutation(len(bodies))]
