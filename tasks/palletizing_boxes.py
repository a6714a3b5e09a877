"""palletizing-boxes: stack 18 scattered boxes on a pallet in three transposed layers (Ravens).

The stack is 2 x 3 boxes per layer, three layers, each layer turned 90 degrees from the one below;
boxes of 9 x 5.7 x 5.7 cm in random shades of brown. One goal step per box, bottom layer first, each
worth 1/18 with the zone metric over the pallet.
"""

from __future__ import annotations

import math

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import multiply
from cliport.tasks import register
from cliport.tasks.base import GoalStep
from cliport.tasks.packing_assets import PALLET_HEIGHT, PALLET_SIZE, ZoneOracleMixin, pallet

STACK = 0.19  # side of the cubic stack (m)
MARGIN = 0.01  # gap between neighbouring boxes
LAYOUT = (2, 3, 3)  # boxes along x, y in the first layer; layers


def stack_poses() -> list[tuple[tuple[float, float, float], float, tuple[float, float, float]]]:
    """(centre in the pallet frame, yaw, box size) of every box, bottom layer first."""
    nx, ny, nz = LAYOUT
    size = np.array(
        [(STACK - (nx - 1) * MARGIN) / nx, (STACK - (ny - 1) * MARGIN) / ny, (STACK - (nz - 1) * MARGIN) / nz]
    )
    out = []
    for z in range(nz):
        cols, rows = (nx, ny) if z % 2 == 0 else (ny, nx)
        sx, sy = (size[0], size[1]) if z % 2 == 0 else (size[1], size[0])
        for iy in range(rows):
            for ix in range(cols):
                x = -STACK / 2 + (ix + 0.5) * sx + ix * MARGIN
                y = -STACK / 2 + (iy + 0.5) * sy + iy * MARGIN
                h = PALLET_HEIGHT + (z + 0.5) * size[2] + z * 0.001
                out.append(((float(x), float(y), float(h)), 0.0 if z % 2 == 0 else math.pi / 2, tuple(size.tolist())))
    return out


@register("palletizing-boxes")
class PalletizingBoxes(ZoneOracleMixin):
    max_steps = 30
    lang_template = "stack all the boxes on the pallet"

    def reset(self, env, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        pose = self.random_pose((*PALLET_SIZE, 0.0), margin=0.01)
        if pose is None:
            raise RuntimeError("no room on the table for the pallet")
        pallet_pose = ((pose[0][0], pose[0][1], 0.0), pose[1])
        pallet(env, pallet_pose)
        zone = [(pallet_pose, (*PALLET_SIZE, 0.25))]
        n = len(stack_poses())
        for centre, yaw, size in stack_poses():
            shade = float(rng.uniform(0.7, 1.0))
            color = (156 * shade, 117 * shade, 95 * shade)
            start = self.random_pose(size)
            if start is None:  # table full: start on a free spot found later by the pile below
                start = ((0.5, 0.0, 0.2 + 0.06 * len(env.objects["rigid"])), (0.0, 0.0, 0.0, 1.0))
            body = env.add_object(shapes.box(env.client, size, start, color))
            local = (centre, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)))
            self.add_goal(
                GoalStep(
                    objects=[body],
                    matches=np.ones((1, 1)),
                    targets=[multiply(pallet_pose, local)],
                    share=1.0 / n,
                    symmetries=[math.pi],
                    rotations=True,
                    metric="zone",
                    zones=zone,
                )
            )
