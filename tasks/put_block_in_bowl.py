"""put-block-in-bowl-{seen,unseen}-colors: put the blocks of one colour in bowls of another colour."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import BLOCK, BOWL, BOWL_TOLERANCE
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_DISTRACTORS = 6


class _PutBlockInBowl(Task):
    """1-3 bowls of the place colour, 1..bowls blocks of the pick colour, six distractor blocks/bowls.

    One goal step holds every target block (each in a different bowl, within 5 cm of its centre as in
    the reference; block yaw ignored), so the reward is 1/n per block placed; ``max_steps`` is the
    number of blocks + 1.
    """

    unseen = False
    max_steps = 10
    place_yaw_informative = False  # round bowls: the expert places at a bowl's random yaw
    done_sentence = "done placing blocks in bowls."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        palette = split_colors(self.mode, self.unseen)
        n_bowls = int(rng.integers(1, 4))
        n_blocks = int(rng.integers(1, n_bowls + 1))
        pick, place = (palette[int(k)] for k in rng.permutation(len(palette))[:2])
        bowl_poses = []
        for _ in range(n_bowls):
            pose = self.random_pose(BOWL, margin=0.01)
            assert pose is not None, "three bowls always fit on an empty table"
            pose = at_height(pose)
            env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS[place]), "fixed")
            bowl_poses.append(pose)
        blocks = []
        for _ in range(n_blocks):
            pose = self.random_pose(BLOCK)
            assert pose is not None, "the target blocks always fit beside the bowls"
            blocks.append(env.add_object(shapes.box(env.client, BLOCK, pose, COLORS[pick])))
        others = [c for c in palette if c not in (pick, place)]
        for k in range(N_DISTRACTORS):
            is_block = rng.random() > 0.5
            pose = self.random_pose(BLOCK if is_block else BOWL, margin=0.01)
            if pose is None:
                continue
            color = COLORS[others[k % len(others)]]
            if is_block:
                env.add_object(shapes.box(env.client, BLOCK, pose, color))
            else:
                pose = at_height(pose)
                env.add_object(shapes.bowl(env.client, env.asset_dir, pose, color), "fixed")
        self.max_steps = n_blocks + 1
        self.add_goal(
            GoalStep(
                objects=blocks,
                matches=np.ones((n_blocks, n_bowls)),
                targets=bowl_poses,
                share=1.0,
                symmetries=[0.0] * n_blocks,
                rotations=True,
                tolerance=BOWL_TOLERANCE,
                lang_goal=f"put the {pick} blocks in a {place} bowl",
            )
        )


@register("put-block-in-bowl-seen-colors")
class PutBlockInBowlSeenColors(_PutBlockInBowl):
    unseen = False


@register("put-block-in-bowl-unseen-colors")
class PutBlockInBowlUnseenColors(_PutBlockInBowl):
    unseen = True
