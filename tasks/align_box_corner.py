"""align-box-corner: slide a box of random size so that one of its corners meets a corner marker."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import at_height, multiply, yaw_to_quat
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.blocks_assets import corner_marker_parts
from cliport.tasks.colors import COLORS
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment


@register("align-box-corner")
class AlignBoxCorner(Task):
    """Four allowed box poses: the marker's own, turned by pi, and the two quarter turns that bring a
    corner of the swapped footprint onto the marker (the box itself counts as having no symmetry)."""

    max_steps = 3
    lang_template = "align the brown box with the green corner"
    done_sentence = "done with alignment."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        sx, sy, sz = (float(v) for v in rng.uniform((0.05, 0.05, 0.01), (0.15, 0.15, 0.06)))
        marker_pose = self.random_pose((sx, sy, 0.0), margin=0.01)
        assert marker_pose is not None, "an empty table always has room for the marker"
        marker_pose = at_height(marker_pose)
        parts = corner_marker_parts((sx, sy, sz))
        env.add_object(shapes.compound(env.client, env.asset_dir, parts, marker_pose, COLORS["green"]), "fixed")
        box_pose = self.random_pose((sx, sy, sz), margin=0.01)
        assert box_pose is not None, "the table always has room for the box beside the marker"
        shade = float(rng.uniform(0.7, 1.3))
        r, g, b = (min(c * shade, 255.0) for c in COLORS["brown"])
        box = env.add_object(shapes.box(env.client, (sx, sy, sz), box_pose, (r, g, b)))
        swapped = (sx / 2 - sy / 2, sy / 2 - sx / 2, 0.0)
        targets = [
            multiply(marker_pose, ((0.0, 0.0, sz / 2), (0.0, 0.0, 0.0, 1.0))),
            multiply(marker_pose, ((0.0, 0.0, sz / 2), yaw_to_quat(math.pi))),
            multiply(marker_pose, ((swapped[0], swapped[1], sz / 2), yaw_to_quat(math.pi / 2))),
            multiply(marker_pose, ((swapped[0], swapped[1], sz / 2), yaw_to_quat(3 * math.pi / 2))),
        ]
        self.add_goal(
            GoalStep(
                objects=[box],
                matches=np.ones((1, 4)),
                targets=targets,
                share=1.0,
                symmetries=[2 * math.pi],
                rotations=True,
            )
        )
