"""place-red-in-green: put every red block into a green bowl, among distractor blocks and bowls."""

from __future__ import annotations

import math

import numpy as np

from cliport.env import shapes
from cliport.tasks import register
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.colors import COLORS

BLOCK = (0.04, 0.04, 0.04)
BOWL = (0.12, 0.12, 0.0)


@register("place-red-in-green")
class PlaceRedInGreen(Task):
    max_steps = 10
    lang_template = "put the red blocks in a green bowl"

    def reset(self, env, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        n_bowls = int(rng.integers(1, 4))
        n_blocks = int(rng.integers(1, n_bowls + 1))
        bowl_poses = []
        for _ in range(n_bowls):
            pose = self.random_pose(BOWL, margin=0.01)
            if pose is None:
                break
            pose = ((pose[0][0], pose[0][1], 0.0), pose[1])
            env.add_object(shapes.bowl(env.client, env.asset_dir, pose, COLORS["green"]), "fixed")
            bowl_poses.append(pose)
        blocks = []
        for _ in range(n_blocks):
            pose = self.random_pose(BLOCK)
            if pose is None:
                break
            blocks.append(env.add_object(shapes.box(env.client, BLOCK, pose, COLORS["red"])))
        distractor_colors = [c for c in COLORS if c not in ("red", "green")]
        for _ in range(6):
            is_block = rng.random() > 0.5
            size = BLOCK if is_block else BOWL
            pose = self.random_pose(size, margin=0.01)
            if pose is None:
                break
            color = COLORS[distractor_colors[int(rng.integers(len(distractor_colors)))]]
            if is_block:
                env.add_object(shapes.box(env.client, BLOCK, pose, color))
            else:
                pose = ((pose[0][0], pose[0][1], 0.0), pose[1])
                env.add_object(shapes.bowl(env.client, env.asset_dir, pose, color), "fixed")
        self.add_goal(
            GoalStep(
                objects=blocks,
                matches=np.ones((len(blocks), len(bowl_poses))),
                targets=bowl_poses,
                share=1.0,
                symmetries=[math.pi / 2] * len(blocks),
                replace=False,
                rotations=True,
            )
        )
