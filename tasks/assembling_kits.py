"""assembling-kits and assembling-kits-seq-{seen,unseen}-colors: put kit shapes onto their silhouettes on a kit board.

The board (0.28 x 0.2 x 0.005 m, static) shows five dark silhouettes of the target shapes at their
target poses; five graspable shapes lie scattered on the table. The goal is the pose metric with
rotation folded by each shape's symmetry. assembling-kits has one step (any object onto any
silhouette of its shape, 1/5 each); the -seq variants name one object and one hole per step.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose, multiply, yaw_to_quat
from cliport.tasks.base import GoalStep
from cliport.tasks.colors import split_colors
from cliport.tasks.kit_shapes import HEIGHT, SHAPES, ShapeTask, placed_pieces, prism_mesh, split_shapes
from cliport.tasks.registry import register, register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

KIT_SIZE = (0.28, 0.2, 0.005)
KIT_COLOR = (0.85, 0.82, 0.75)
SILHOUETTE_COLOR = (0.2, 0.2, 0.2)
SILHOUETTE_THICKNESS = 0.0015  # visual only; thinner ones flicker in the fused depth
# Target centres in the board frame: three holes in one row, two in the other.
HOLE_OFFSETS = [(-0.09, 0.045), (0.0, 0.045), (0.09, 0.045), (-0.045, -0.045), (0.045, -0.045)]
N_OBJECTS = 5


class KitTask(ShapeTask):
    """Shared scene building of the assembling-kits family."""

    def build_kit(self, shape_ids: list[int]) -> list[Pose]:
        """Add the board with a silhouette of each shape (random yaw) and return the target poses."""
        env, rng = self.env, self.rng
        kit_pose = self.random_pose(KIT_SIZE)
        if kit_pose is None:
            raise RuntimeError("no room on the table for the kit board")
        yaws = [float(rng.uniform(0, 2 * math.pi)) for _ in shape_ids]
        top = KIT_SIZE[2] / 2
        outlines = [
            piece
            for shape, xy, yaw in zip(shape_ids, HOLE_OFFSETS, yaws, strict=False)
            for piece in placed_pieces(shape, xy, yaw)
        ]
        silhouettes = {**prism_mesh(outlines, top, SILHOUETTE_THICKNESS), "collide": False, "color": SILHOUETTE_COLOR}
        parts: list[dict] = [{"type": "box", "size": KIT_SIZE}, silhouettes]
        env.add_object(shapes.compound(env.client, env.asset_dir, parts, kit_pose, color=KIT_COLOR), "fixed")
        return [
            multiply(kit_pose, ((dx, dy, top + HEIGHT / 2), yaw_to_quat(yaw)))
            for (dx, dy), yaw in zip(HOLE_OFFSETS, yaws, strict=False)
        ]


@register("assembling-kits")
class AssemblingKits(KitTask):
    max_steps = 10
    lang_template = "put all the blocks inside the holes they fit in"
    done_sentence = "done assembling blocks."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        shape_ids = [int(s) for s in rng.choice(split_shapes(self.mode), N_OBJECTS)]
        colors = [str(c) for c in rng.permutation(split_colors(self.mode, unseen=False))[:N_OBJECTS]]
        targets = self.build_kit(shape_ids)
        objects = self.add_shapes(shape_ids, colors)
        ids = np.asarray(shape_ids)
        self.add_goal(
            GoalStep(
                objects=objects,
                matches=ids[:, None] == ids[None, :],
                targets=targets,
                share=1.0,
                symmetries=[SHAPES[s].symmetry for s in shape_ids],
                rotations=True,
            )
        )


def spatial_word(i: int, shape_ids: list[int], positions: list[np.ndarray]) -> str:
    """'' when hole i's shape is unique, else where it lies among the holes of the same shape.

    The reference's convention in world coordinates: 'top' when its x is the smallest and the x
    separation dominates, 'bottom' the same with the largest x, else 'left' (smallest y), 'right'
    (largest y), else 'middle'; each followed by a space.
    """
    others = [positions[j] for j, s in enumerate(shape_ids) if j != i and s == shape_ids[i]]
    if not others:
        return ""
    x, y = positions[i][0], positions[i][1]
    if all(x < o[0] and abs(x - o[0]) > abs(y - o[1]) for o in others):
        return "top "
    if all(x > o[0] and abs(x - o[0]) > abs(y - o[1]) for o in others):
        return "bottom "
    if all(y < o[1] for o in others):
        return "left "
    if all(y > o[1] for o in others):
        return "right "
    return "middle "


class AssemblingKitsSeq(KitTask):
    """One named object into one named hole per step."""

    max_steps = 5
    template = "put the {color} {shape} in the {loc}{shape} hole"
    done_sentence = "done assembling kit."
    unseen = True

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        shape_ids = [int(s) for s in rng.choice(split_shapes(self.mode), N_OBJECTS)]
        colors = [str(c) for c in rng.permutation(split_colors(self.mode, self.unseen))[:N_OBJECTS]]
        targets = self.build_kit(shape_ids)
        objects = self.add_shapes(shape_ids, colors)
        self.kit = (objects, shape_ids, targets)
        positions = [np.asarray(t[0]) for t in targets]
        for i in rng.permutation(N_OBJECTS):
            i = int(i)
            shape = SHAPES[shape_ids[i]]
            self.add_goal(
                GoalStep(
                    objects=[objects[i]],
                    matches=np.ones((1, 1)),
                    targets=[targets[i]],
                    share=1.0 / N_OBJECTS,
                    symmetries=[shape.symmetry],
                    rotations=True,
                    lang_goal=self.template.format(
                        color=colors[i], shape=shape.label, loc=spatial_word(i, shape_ids, positions)
                    ),
                )
            )

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """Each object into a hole of its shape, in a random order. Where several objects share a shape, which
        goes into which of their holes is a random guess (the instruction names it by colour and place)."""
        objects, shape_ids, targets = self.kit
        hole_of = list(range(N_OBJECTS))
        for shape in set(shape_ids):
            same = [i for i in range(N_OBJECTS) if shape_ids[i] == shape]
            for i, j in zip(same, rng.permutation(same), strict=True):
                hole_of[i] = int(j)
        return [
            GoalStep(
                objects=[objects[i]],
                matches=np.ones((1, 1)),
                targets=[targets[hole_of[i]]],
                share=1.0 / N_OBJECTS,
                symmetries=[SHAPES[shape_ids[i]].symmetry],
                rotations=True,
            )
            for i in map(int, rng.permutation(N_OBJECTS))
        ]


AssemblingKitsSeqSeenColors, AssemblingKitsSeqUnseenColors = register_splits(
    AssemblingKitsSeq, "assembling-kits-seq-seen-colors", "assembling-kits-seq-unseen-colors"
)
