"""block-insertion: insert an L-shaped block into the L-shaped slot of a static fixture."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import ELL_HEIGHT, ELL_SIZE, FIXTURE_SIZE, ell_polygon, fixture_parts
from cliport.tasks.colors import COLORS
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment


@register("block-insertion")
class BlockInsertion(Task):
    """One pick-and-place: the block's pose must match the fixture's (the L has no yaw symmetry)."""

    max_steps = 3
    lang_template = "put the L shape block in the L shape hole"
    done_sentence = "done with insertion."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        fixture_pose = self.random_pose(FIXTURE_SIZE, margin=0.01)
        assert fixture_pose is not None, "an empty table always has room for the fixture"
        fixture_pose = at_height(fixture_pose)
        env.add_object(
            shapes.compound(env.client, env.asset_dir, fixture_parts(), fixture_pose, color=COLORS["brown"]),
            "fixed",
        )
        block_pose = self.random_pose((ELL_SIZE, ELL_SIZE, ELL_HEIGHT), margin=0.01)
        assert block_pose is not None, "the table always has room for the block beside the fixture"
        block_pose = at_height(block_pose)
        block = env.add_object(
            shapes.extruded_polygon(env.client, env.asset_dir, ell_polygon(), ELL_HEIGHT, block_pose, COLORS["red"])
        )
        self.add_goal(
            GoalStep(
                objects=[block],
                matches=np.ones((1, 1)),
                targets=[fixture_pose],
                share=1.0,
                symmetries=[2 * math.pi],
                rotations=True,
            )
        )
