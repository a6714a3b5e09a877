"""Rope builder: a chain of small sphere beads joined by point-to-point constraints."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.bullet import p

if TYPE_CHECKING:
    from cliport.env.environment import Environment

N_BEADS = 20
BEAD_RADIUS = 0.005
# Ravens' rope: the target side is 2 * radius * n * sqrt(2) long and each bead covers 1/n of it.
SIDE_LENGTH = 2 * BEAD_RADIUS * N_BEADS * math.sqrt(2)
SPACING = SIDE_LENGTH / N_BEADS
BEAD_MASS = 0.1
CONSTRAINT_FORCE = 100.0


def rope_path(rng: np.random.Generator, bounds: np.ndarray, margin: float = 0.04, tries: int = 200) -> np.ndarray:
    """Bead centres (N_BEADS, 2) of a random smooth curve lying inside ``bounds`` (xy) by ``margin``."""
    lo = bounds[:2, 0] + margin
    hi = bounds[:2, 1] - margin
    for _ in range(tries):
        heading = rng.uniform(0, 2 * math.pi)
        points = [rng.uniform(lo, hi)]
        for _ in range(N_BEADS - 1):
            heading += rng.normal(0.0, 0.35)
            points.append(points[-1] + SPACING * np.array([math.cos(heading), math.sin(heading)]))
        path = np.asarray(points)
        if np.all(path >= lo) and np.all(path <= hi):
            return path
    raise RuntimeError("could not fit the rope inside the workspace")


def make_rope(env: Environment, path: np.ndarray, color: shapes.Color, end_color: shapes.Color) -> list[int]:
    """Beads at ``path`` (N, 2) resting on the table, consecutive beads joined at their midpoint.

    Each bead is registered as a "deformable" object (graspable by suction). The end beads get
    ``end_color`` so that the two ends are visible.
    """
    beads: list[int] = []
    for k, (x, y) in enumerate(path):
        c = end_color if k in (0, len(path) - 1) else color
        bead = shapes.sphere(env.client, BEAD_RADIUS, ((float(x), float(y), BEAD_RADIUS), (0, 0, 0, 1)), c, BEAD_MASS)
        p.changeDynamics(
            bead,
            -1,
            lateralFriction=0.5,
            rollingFriction=0.01,
            spinningFriction=0.01,
            linearDamping=0.5,
            angularDamping=0.9,
            physicsClientId=env.client,
        )
        if beads:
            half = (path[k] - path[k - 1]) / 2  # both beads start unrotated: world offsets are body offsets
            constraint = p.createConstraint(
                beads[-1],
                -1,
                bead,
                -1,
                p.JOINT_POINT2POINT,
                (0, 0, 0),
                (float(half[0]), float(half[1]), 0.0),
                (float(-half[0]), float(-half[1]), 0.0),
                physicsClientId=env.client,
            )
            p.changeConstraint(constraint, maxForce=CONSTRAINT_FORCE, physicsClientId=env.client)
        # Neighbours never collide: a bead held by suction would otherwise "touch" the bead hanging
        # from it and be released in the air instead of being lowered onto the table.
        for other in beads[-2:]:
            p.setCollisionFilterPair(other, bead, -1, -1, 0, physicsClientId=env.client)
        beads.append(env.add_object(bead, "deformable"))
    return beads
