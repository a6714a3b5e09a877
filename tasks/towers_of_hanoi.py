"""towers-of-hanoi(-seq-{seen,unseen}-colors): move three rings from one rod of the stand to another."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height, multiply
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import (
    BROWN_SHADES,
    RING_HEIGHT,
    RING_OUTERS,
    ROD_Y,
    STAND_SIZE,
    ring_parts,
    stand_parts,
)
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register, register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

RING_MASS = 0.05
ROD_NAMES = ("lighter brown side", "middle of the stand", "darker brown side")


def hanoi_moves(n: int, source: int = 0, target: int = 2, spare: int = 1) -> list[tuple[int, int, int]]:
    """The optimal move sequence as (ring, from rod, to rod); ring 0 is the smallest."""
    if n == 0:
        return []
    return [
        *hanoi_moves(n - 1, source, spare, target),
        (n - 1, source, target),
        *hanoi_moves(n - 1, spare, target, source),
    ]


class _TowersScene(Task):
    """Stand at a random pose (ends shaded lighter to darker along its +y); rings stacked on rod 0.

    One goal step per move of the optimal solution (1/7 each); the pose metric ignores ring yaw.
    """

    max_steps = 14
    place_yaw_informative = False  # round rings, placed without turning (place yaw 0)
    done_sentence = "solved towers of hanoi."

    def ring_colors(self, rng: np.random.Generator) -> list[str]:
        return ["gray", "gray", "gray"]

    def move_text(self, color: str, rod: int) -> str | None:
        return None

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        base_pose = self.random_pose(STAND_SIZE, margin=0.02)
        assert base_pose is not None, "an empty table always has room for the stand"
        base_pose = at_height(base_pose)
        env.add_object(shapes.compound(env.client, env.asset_dir, stand_parts(BROWN_SHADES), base_pose), "fixed")
        rods = [multiply(base_pose, ((0.0, y, STAND_SIZE[2]), (0.0, 0.0, 0.0, 1.0))) for y in ROD_Y]
        colors = self.ring_colors(rng)
        rings = []
        for k, outer in enumerate(RING_OUTERS):
            level = len(RING_OUTERS) - 1 - k  # the largest ring at the bottom
            pose = multiply(rods[0], ((0.0, 0.0, level * RING_HEIGHT + 0.001), (0.0, 0.0, 0.0, 1.0)))
            parts = ring_parts(outer)
            body = shapes.compound(env.client, env.asset_dir, parts, pose, color=COLORS[colors[k]], mass=RING_MASS)
            rings.append(env.add_object(body))
        for ring, _, rod in hanoi_moves(len(rings)):
            self.add_goal(
                GoalStep(
                    objects=[rings[ring]],
                    matches=np.ones((1, 1)),
                    targets=[rods[rod]],
                    share=1 / 7,
                    symmetries=[0.0],
                    rotations=False,
                    lang_goal=self.move_text(colors[ring], rod),
                )
            )


@register("towers-of-hanoi")
class TowersOfHanoi(_TowersScene):
    lang_template = "solve towers of hanoi"


class _TowersOfHanoiSeq(_TowersScene):
    unseen = False

    def ring_colors(self, rng: np.random.Generator) -> list[str]:
        palette = split_colors(self.mode, self.unseen)
        return [palette[int(k)] for k in rng.permutation(len(palette))[:3]]

    def move_text(self, color: str, rod: int) -> str | None:
        return f"move the {color} ring to the {ROD_NAMES[rod]}"

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """The instructions' own moves in their order: the puzzle's rules force the optimal solution's order,
        whatever colours the instructions name, so a blind expert makes the same moves as the oracle."""
        return list(self.goals)


TowersOfHanoiSeqSeenColors, TowersOfHanoiSeqUnseenColors = register_splits(
    _TowersOfHanoiSeq, "towers-of-hanoi-seq-seen-colors", "towers-of-hanoi-seq-unseen-colors"
)
