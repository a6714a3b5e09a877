"""Procedural rigid bodies made directly from PyBullet collision/visual shapes (no mesh files)."""

from __future__ import annotations

import pybullet as p

from cliport.env.transforms import Pose

Color = tuple[float, float, float]


def _rgba(color: Color, alpha: float = 1.0) -> list[float]:
    if max(color) > 1.0:  # 0-255 colours
        color = tuple(c / 255.0 for c in color)  # type: ignore[assignment]
    return [*color, alpha]


def box(
    client: int,
    size: tuple[float, float, float],
    pose: Pose,
    color: Color = (0.5, 0.5, 0.5),
    mass: float = 0.1,
    friction: float = 0.5,
    collide: bool = True,
) -> int:
    """A box of full extents ``size`` (m); ``mass`` 0 makes it static."""
    half = [s / 2 for s in size]
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client) if collide else -1
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=_rgba(color), physicsClientId=client)
    body = p.createMultiBody(mass, col, vis, pose[0], pose[1], physicsClientId=client)
    p.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=client)
    return body


def cylinder(
    client: int,
    radius: float,
    height: float,
    pose: Pose,
    color: Color = (0.5, 0.5, 0.5),
    mass: float = 0.1,
    friction: float = 0.5,
) -> int:
    """An upright cylinder (axis along the pose's z)."""
    col = p.createCollisionShape(p.GEOM_CYLINDER, radius=radius, height=height, physicsClientId=client)
    vis = p.createVisualShape(
        p.GEOM_CYLINDER, radius=radius, length=height, rgbaColor=_rgba(color), physicsClientId=client
    )
    body = p.createMultiBody(mass, col, vis, pose[0], pose[1], physicsClientId=client)
    p.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=client)
    return body


def sphere(
    client: int, radius: float, pose: Pose, color: Color = (0.5, 0.5, 0.5), mass: float = 0.1, friction: float = 0.5
) -> int:
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client)
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=radius, rgbaColor=_rgba(color), physicsClientId=client)
    body = p.createMultiBody(mass, col, vis, pose[0], pose[1], physicsClientId=client)
    p.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=client)
    return body
