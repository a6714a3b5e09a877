"""place-red-in-green: put every red block into a green bowl, among distractor blocks and bowls."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import BLOCK, BOWL, BOWL_TOLERANCE
from cliport.tasks.colors import COLORS
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_DISTRACTORS = 10


@register("place-red-in-green")
class PlaceRedInGreen(Task):
    """1-3 green bowls, 1..bowls red blocks, up to ten distractor blocks and bowls in other colours
    (the reference retries until ten fit; ours stops at the first that finds no free spot).

    As in the reference, a red block counts once it is within 5 cm of a free green bowl's centre,
    whatever its yaw; one goal step holds every red block, so each is worth 1/n.
    """

    max_steps = 10
    place_yaw_informative = False  # round bowls: the expert places at a bowl's random yaw
    lang_template = "put the red blocks in a green bowl"

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        n_bowls = int(rng.integers(1, 4))
        n_blocks = int(rng.integers(1, n_bowls + 1))
        bowl_poses = []
        for _ in range(n_bowls):
            pose = self.random_pose(BOWL, margin=0.01)
            if pose is None:
                break
            pose = at_height(pose)
            env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS["green"]), "fixed")
            bowl_poses.append(pose)
        blocks = []
        for _ in range(n_blocks):
            pose = self.random_pose(BLOCK)
            if pose is None:
                break
            blocks.append(env.add_object(shapes.box(env.client, BLOCK, pose, COLORS["red"])))
        block_colors = [c for c in COLORS if c != "red"]
        bowl_colors = [c for c in COLORS if c != "green"]
        for k in range(N_DISTRACTORS):
            is_block = rng.random() > 0.5
            pose = self.random_pose(BLOCK if is_block else BOWL, margin=0.01)
            if pose is None:
                break
            if is_block:
                color = COLORS[block_colors[k % len(block_colors)]]
                env.add_object(shapes.box(env.client, BLOCK, pose, color))
            else:
                color = COLORS[bowl_colors[k % len(bowl_colors)]]
                pose = at_height(pose)
                env.add_object(shapes.bowl(env.client, env.asset_dir, pose, color), "fixed")
        self.add_goal(
            GoalStep(
                objects=blocks,
                matches=np.ones((len(blocks), len(bowl_poses))),
                targets=bowl_poses,
                share=1.0,
                symmetries=[0.0] * len(blocks),
                replace=False,
                rotations=True,
                tolerance=BOWL_TOLERANCE,
            )
        )
