"""palletizing-boxes: stack 18 boxes on a pallet in three transposed layers (Ravens).

As in the reference, the pallet stands at a fixed place on the far (+y) half of the table and the
boxes arrive one at a time: whenever no box is left on the near half, the next one is dropped at a
fixed spot there with a random yaw. Boxes not yet in play wait off the table, out of every camera's
view. The stack is 2 x 3 boxes per layer, three layers, each layer turned 90 degrees from the one
below; boxes of 9 x 5.7 x 5.7 cm in random shades of brown. The order is a time-reversed random
unstacking (bottom layer first, random order within a layer). One goal step per box in that order,
each worth 1/18 with the zone metric over the pallet.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from cliport.env import shapes
from cliport.env.bullet import p
from cliport.env.transforms import multiply, yaw_to_quat
from cliport.tasks.base import GoalStep
from cliport.tasks.packing_assets import PALLET_HEIGHT, PALLET_SIZE, ZoneOracleMixin, pallet
from cliport.tasks.registry import register

if TYPE_CHECKING:
    from cliport.env.environment import Environment

STACK = 0.19  # side of the cubic stack (m)
MARGIN = 0.01  # gap between neighbouring boxes
LAYOUT = (2, 3, 3)  # boxes along x, y in the first layer; layers
PALLET_POSE = ((0.5, 0.25, 0.0), (0.0, 0.0, 0.0, 1.0))
SPAWN_XY = (0.5, -0.25)
SPAWN_DROP = 0.1  # height the next box is dropped from (m)
DROP_STEPS = 120  # simulation steps (0.5 s) before waiting for the dropped box to settle
NEAR_HALF = ((0.25, 0.75), (-0.5, 0.0))  # x and y range of the table half where boxes arrive
PARK_X = 1.75  # waiting boxes stand in a row here, beyond what any camera sees


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

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        pallet(env, PALLET_POSE)
        zone = [(PALLET_POSE, (*PALLET_SIZE, 0.25))]
        layouts = stack_poses()
        per_layer = LAYOUT[0] * LAYOUT[1]
        order = [layer * per_layer + int(k) for layer in range(LAYOUT[2]) for k in rng.permutation(per_layer)]
        self.waiting: list[int] = []
        for n, index in enumerate(order):
            centre, yaw, size = layouts[index]
            shade = float(rng.uniform(0.7, 1.0))
            color = (156 * shade, 117 * shade, 95 * shade)
            parked = ((PARK_X, -1.8 + 0.2 * n, size[2] / 2), (0.0, 0.0, 0.0, 1.0))
            body = env.add_object(shapes.box(env.client, size, parked, color))
            self.waiting.append(body)
            local = (centre, yaw_to_quat(yaw))
            self.add_goal(
                GoalStep(
                    objects=[body],
                    matches=np.ones((1, 1)),
                    targets=[multiply(PALLET_POSE, local)],
                    share=1.0 / len(order),
                    symmetries=[math.pi],
                    rotations=True,
                    metric="zone",
                    zones=zone,
                )
            )
        self.spawn_box()

    def reward(self) -> tuple[float, dict[str, Any]]:
        delta, info = super().reward()
        if self.spawn_box():
            info["spawned"] = True
        return delta, info

    def spawn_box(self) -> bool:
        """Drop the next waiting box at the spawn spot if no box is on the near half; True if one was."""
        if not self.waiting:
            return False
        (x0, x1), (y0, y1) = NEAR_HALF
        for body in (b for step in self.goals for b in step.objects):
            x, y, _ = self._pose(body)[0]
            if x0 <= x <= x1 and y0 <= y <= y1:
                return False
        body = self.waiting.pop(0)
        size = self.object_half_extents(body) * 2
        yaw = float(self.rng.uniform(0, 2 * math.pi))
        pose = ((*SPAWN_XY, SPAWN_DROP + size[2] / 2), yaw_to_quat(yaw))
        p.resetBasePositionAndOrientation(body, *pose, physicsClientId=self.env.client)
        for _ in range(DROP_STEPS):  # it starts at rest, so settle() alone would return at once
            p.stepSimulation(physicsClientId=self.env.client)
        self.env.settle()
        return True
