"""Procedural rigid bodies made directly from PyBullet collision/visual shapes (no mesh files)."""

from __future__ import annotations

import hashlib
import math
import os

import numpy as np

from cliport.env.bullet import p
from cliport.env.transforms import Pose

Color = tuple[float, float, float]


def _rgba(color: Color, alpha: float = 1.0) -> list[float]:
    if max(color) > 1.0:  # 0-255 colours
        r, g, b = color
        color = (r / 255.0, g / 255.0, b / 255.0)
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


def _write_once(directory: str, suffix: str, text: str) -> str:
    """Write ``text`` to a file named by its hash (so identical assets are written once) and return the path."""
    path = os.path.join(directory, hashlib.sha1(text.encode()).hexdigest()[:16] + suffix)
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return path


def _obj_text(vertices: list[list[float]], faces: list[tuple[int, int, int]]) -> str:
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def _geometry(part: dict, asset_dir: str) -> str:
    kind = part["type"]
    if kind == "box":
        sx, sy, sz = part["size"]
        return f'<box size="{sx} {sy} {sz}"/>'
    if kind == "cylinder":
        return f'<cylinder radius="{part["radius"]}" length="{part["height"]}"/>'
    if kind == "sphere":
        return f'<sphere radius="{part["radius"]}"/>'
    if kind == "mesh":
        path = _write_once(asset_dir, ".obj", _obj_text(part["vertices"], part["faces"]))
        return f'<mesh filename="{path}" scale="1 1 1"/>'
    raise ValueError(f"unknown part type {kind!r}")


def _origin(part: dict) -> str:
    x, y, z = part.get("position", (0.0, 0.0, 0.0))
    r, pch, yw = part.get("rpy", (0.0, 0.0, 0.0))
    return f'<origin xyz="{x} {y} {z}" rpy="{r} {pch} {yw}"/>'


def compound(
    client: int,
    asset_dir: str,
    parts: list[dict],
    pose: Pose,
    color: Color = (0.5, 0.5, 0.5),
    mass: float = 0.0,
    friction: float = 0.5,
) -> int:
    """One rigid body made of several parts, e.g. a concave bowl or a stand with rods.

    Each part is a dict with ``type``: "box" (``size``), "cylinder" (``radius``, ``height``),
    "sphere" (``radius``) or "mesh" (``vertices``, ``faces``; convex for dynamic bodies), a
    ``position`` and ``rpy`` in the body frame, an optional ``color`` and ``collide`` (default
    True) / ``visual`` (default True) flags. Built as a one-link URDF in ``asset_dir`` (PyBullet
    makes a compound collision shape of its elements); ``mass`` 0 makes it static.
    """
    elements = []
    for k, part in enumerate(parts):
        geom = f"<geometry>{_geometry(part, asset_dir)}</geometry>"
        if part.get("visual", True):
            rgba = " ".join(f"{c:.4f}" for c in _rgba(part.get("color", color)))
            elements.append(
                f'<visual>{_origin(part)}{geom}<material name="m{k}"><color rgba="{rgba}"/></material></visual>'
            )
        if part.get("collide", True):
            elements.append(f"<collision>{_origin(part)}{geom}</collision>")
    inertia = max(mass, 1e-3) * 1e-4
    # One element per line: PyBullet's URDF parser fails on lines longer than about 10k characters.
    urdf = "\n".join(
        [
            '<?xml version="1.0"?>',
            '<robot name="compound"><link name="base">',
            f'<contact><lateral_friction value="{friction}"/></contact>',
            f'<inertial><origin xyz="0 0 0"/><mass value="{mass}"/>',
            f'<inertia ixx="{inertia}" ixy="0" ixz="0" iyy="{inertia}" iyz="0" izz="{inertia}"/></inertial>',
            *elements,
            "</link></robot>",
            "",
        ]
    )
    path = _write_once(asset_dir, ".urdf", urdf)
    body = p.loadURDF(path, pose[0], pose[1], useFixedBase=mass == 0.0, physicsClientId=client)
    return body


def ring_wall_parts(
    mid_radius: float, thickness: float, length: float, height: float, segments: int, **flags: bool
) -> list[dict]:
    """``segments`` box parts (for :func:`compound`) standing in a circle from z = 0 to ``height``.

    Each box is ``thickness`` deep radially, centred on ``mid_radius``, and ``length`` long
    tangentially; ``flags`` (``visual`` / ``collide``) are copied into every part.
    """
    parts = []
    for k in range(segments):
        a = 2 * math.pi * k / segments
        parts.append(
            {
                "type": "box",
                "size": (thickness, length, height),
                "position": (mid_radius * math.cos(a), mid_radius * math.sin(a), height / 2),
                "rpy": (0.0, 0.0, a),
                **flags,
            }
        )
    return parts


def bowl(
    client: int,
    asset_dir: str,
    pose: Pose,
    color: Color,
    radius: float = 0.06,
    wall_height: float = 0.03,
    wall_thickness: float = 0.006,
    segments: int = 16,
) -> int:
    """A static, concave bowl: a flat base disc and a ring of wall slabs (outer radius ``radius``)."""
    parts: list[dict] = [{"type": "cylinder", "radius": radius, "height": 0.004, "position": (0, 0, 0.002)}]
    slab = 2 * radius * math.tan(math.pi / segments)
    parts += ring_wall_parts(radius - wall_thickness / 2, wall_thickness, slab, wall_height, segments)
    return compound(client, asset_dir, parts, pose, color=color, mass=0.0)


def _triangulate(polygon: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear-clipping triangulation of a simple polygon (counter-clockwise or clockwise)."""
    pts = [tuple(v) for v in polygon]
    idx = list(range(len(pts)))
    area = sum(pts[i][0] * pts[(i + 1) % len(pts)][1] - pts[(i + 1) % len(pts)][0] * pts[i][1] for i in idx)
    if area < 0:
        idx.reverse()

    def cross(o: tuple[float, ...], a: tuple[float, ...], b: tuple[float, ...]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def inside(pt: tuple[float, ...], a: tuple[float, ...], b: tuple[float, ...], c: tuple[float, ...]) -> bool:
        return cross(a, b, pt) >= 0 and cross(b, c, pt) >= 0 and cross(c, a, pt) >= 0

    triangles = []
    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = pts[i0], pts[i1], pts[i2]
            if cross(a, b, c) <= 1e-12:
                continue
            if any(inside(pts[m], a, b, c) for m in idx if m not in (i0, i1, i2)):
                continue
            triangles.append((i0, i1, i2))
            idx.pop(k)
            break
        else:
            raise ValueError("polygon could not be triangulated (is it simple?)")
    triangles.append((idx[0], idx[1], idx[2]))
    return triangles


def prism_parts(
    polygon: np.ndarray | list[tuple[float, float]], height: float, color: Color | None = None, z0: float = 0.0
) -> list[dict]:
    """Parts (for ``compound``) of a 2-D simple polygon extruded from z0 to z0 + height.

    Collision: one convex triangular prism per triangle (concave outlines such as letters work for
    dynamic bodies). Visual: one mesh of the whole prism.
    """
    poly = np.asarray(polygon, dtype=float)
    tris = _triangulate(poly)
    n = len(poly)
    verts = [[x, y, z0] for x, y in poly] + [[x, y, z0 + height] for x, y in poly]
    faces: list[tuple[int, int, int]] = []
    for a, b, c in tris:
        faces += [(a, c, b), (a + n, b + n, c + n)]
    ccw = sum(poly[i, 0] * poly[(i + 1) % n, 1] - poly[(i + 1) % n, 0] * poly[i, 1] for i in range(n)) > 0
    for i in range(n):
        j = (i + 1) % n
        a, b = (i, j) if ccw else (j, i)
        faces += [(a, b, b + n), (a, b + n, a + n)]
    extra = {} if color is None else {"color": color}
    parts: list[dict] = [{"type": "mesh", "vertices": verts, "faces": faces, "collide": False, **extra}]
    for a, b, c in tris:
        tri = poly[[a, b, c]]
        prism = [[x, y, z0] for x, y in tri] + [[x, y, z0 + height] for x, y in tri]
        prism_faces = [(0, 2, 1), (3, 4, 5), (0, 1, 4), (0, 4, 3), (1, 2, 5), (1, 5, 4), (2, 0, 3), (2, 3, 5)]
        parts.append({"type": "mesh", "vertices": prism, "faces": prism_faces, "visual": False})
    return parts


def extruded_polygon(
    client: int,
    asset_dir: str,
    polygon: np.ndarray | list[tuple[float, float]],
    height: float,
    pose: Pose,
    color: Color = (0.5, 0.5, 0.5),
    mass: float = 0.1,
    friction: float = 0.5,
) -> int:
    """A prism: a simple 2-D polygon (metres, body frame) extruded from z = 0 to ``height``."""
    return compound(client, asset_dir, prism_parts(polygon, height), pose, color=color, mass=mass, friction=friction)
