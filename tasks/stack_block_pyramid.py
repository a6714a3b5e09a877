"""stack-block-pyramid(-seq-{seen,unseen}-colors): stack six blocks into a 3-2-1 pyramid on a three-tile base."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose, at_height, multiply
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import (
    BLOCK,
    BROWN_SHADES,
    PYRAMID_BASE_SIZE,
    pyramid_base_parts,
    pyramid_targets,
)
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register, register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

BLOCK_SYMMETRY = math.pi / 2


class _PyramidScene(Task):
    """Shared scene: a static three-tile base at a random pose and six blocks around it."""

    max_steps = 12
    done_sentence = "done stacking block pyramid."

    def build(self, env: Environment, block_colors: list[str]) -> tuple[list[int], list[Pose]]:
        """Add the base (tiles lightest to darkest along its +y) and one block per colour; return the
        block ids and the six target poses (bottom row lightest to darkest tile, middle row, top)."""
        base_pose = self.random_pose(PYRAMID_BASE_SIZE, margin=0.02)
        assert base_pose is not None, "an empty table always has room for the base"
        base_pose = at_height(base_pose)
        parts = pyramid_base_parts(BROWN_SHADES)
        env.add_object(shapes.compound(env.client, env.asset_dir, parts, base_pose), "fixed")
        targets = [multiply(base_pose, (xyz, (0.0, 0.0, 0.0, 1.0))) for xyz in pyramid_targets()]
        blocks = []
        for name in block_colors:
            pose = self.random_pose(BLOCK)
            assert pose is not None, "six blocks always fit on the table"
            blocks.append(env.add_object(shapes.box(env.client, BLOCK, pose, COLORS[name])))
        return blocks, targets


@register("stack-block-pyramid")
class StackBlockPyramid(_PyramidScene):
    """Rows as goal steps: bottom (3 blocks, any order), middle (2), top (1); 1/6 of the reward per block."""

    COLORS_BY_ROW = (("purple", "blue", "green"), ("yellow", "orange"), ("red",))
    ROW_TEXT = ("the green, blue and purple blocks", "the yellow and orange blocks", "the red block")

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        colors = [c for row in self.COLORS_BY_ROW for c in row]
        blocks, targets = self.build(env, colors)
        start = 0
        for row, (names, text) in enumerate(zip(self.COLORS_BY_ROW, self.ROW_TEXT, strict=True)):
            n = len(names)
            self.add_goal(
                GoalStep(
                    objects=blocks[start : start + n],
                    matches=np.ones((n, n)),
                    targets=targets[start : start + n],
                    share=n / 6,
                    symmetries=[BLOCK_SYMMETRY] * n,
                    rotations=True,
                    lang_goal=f"make the {('bottom', 'middle', 'top')[row]} row with {text}",
                )
            )
            start += n


class _StackBlockPyramidSeq(_PyramidScene):
    """One block per goal step (1/6 each), named by colour and by what it goes on."""

    unseen = False
    lang_template = None

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        palette = split_colors(self.mode, self.unseen)
        names = [palette[int(k)] for k in rng.permutation(len(palette))[:6]]
        blocks, targets = self.build(env, names)
        self.pyramid = (blocks, targets)
        places = [
            "the lightest brown block",
            "the middle brown block",
            "the darkest brown block",
            f"the {names[0]} and {names[1]} blocks",
            f"the {names[1]} and {names[2]} blocks",
            f"the {names[3]} and {names[4]} blocks",
        ]
        for block, target, name, place in zip(blocks, targets, names, places, strict=True):
            self.add_goal(
                GoalStep(
                    objects=[block],
                    matches=np.ones((1, 1)),
                    targets=[target],
                    share=1 / 6,
                    symmetries=[BLOCK_SYMMETRY],
                    rotations=True,
                    lang_goal=f"put the {name} block on {place}",
                )
            )

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """The six places in the order the task always names them (bottom row lightest to darkest tile, then
        the middle row, then the top, as stacking forces), each with a block guessed at random: which colour
        goes where is the instruction's, drawn independently of the scene."""
        blocks, targets = self.pyramid
        return [
            GoalStep(
                objects=[blocks[int(k)]],
                matches=np.ones((1, 1)),
                targets=[target],
                share=1 / 6,
                symmetries=[BLOCK_SYMMETRY],
                rotations=True,
            )
            for k, target in zip(rng.permutation(len(blocks)), targets, strict=True)
        ]


StackBlockPyramidSeqSeenColors, StackBlockPyramidSeqUnseenColors = register_splits(
    _StackBlockPyramidSeq, "stack-block-pyramid-seq-seen-colors", "stack-block-pyramid-seq-unseen-colors"
)
