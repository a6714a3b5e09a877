"""The 20 kit shapes of the kitting tasks (assembling-kits, packing-shapes): outlines, names, symmetries, builders.

Every shape is a 2-D outline about 6 cm across, extruded 2 cm tall, made of a few convex pieces
(letters with holes such as A, R and the ring are unions of convex pieces, so no polygon has a hole).
A body is one visual mesh of the whole outline plus one convex collision mesh per piece, which keeps
the number of collision shapes per body small. The body frame's origin is the shape's centre of rotational
symmetry (the bounding-box centre for shapes without one), mid-height.

Index order follows Ravens: train shapes are 0-13, unseen (val/test) shapes are 14-19.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose, invert, multiply, quat_to_yaw, yaw_to_quat
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.colors import COLORS

if TYPE_CHECKING:
    from cliport.env.environment import Environment

HEIGHT = 0.02  # extrusion height (m)
TRAIN_SHAPES = list(range(14))
TEST_SHAPES = list(range(14, 20))
_CM = 0.01


@dataclass(frozen=True)
class KitShape:
    """name: short id; label: how instructions name it; pieces: convex CCW polygons (m, body frame);
    symmetry: yaw symmetry period in radians (0 = any yaw, 2*pi = none)."""

    name: str
    label: str
    pieces: tuple[np.ndarray, ...]
    symmetry: float

    @property
    def half_extents(self) -> np.ndarray:
        """Half extents (x, y, z) of the shape's box in its own frame (centred on the origin)."""
        pts = np.concatenate(self.pieces)
        return np.array([np.abs(pts[:, 0]).max(), np.abs(pts[:, 1]).max(), HEIGHT / 2])


def _ccw(poly: np.ndarray) -> np.ndarray:
    area = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    return poly if area > 0 else poly[::-1]


def _regular(n: int, radius: float, centre: tuple[float, float] = (0.0, 0.0), phase: float = 0.0) -> list:
    return [
        (
            centre[0] + radius * math.cos(phase + 2 * math.pi * k / n),
            centre[1] + radius * math.sin(phase + 2 * math.pi * k / n),
        )
        for k in range(n)
    ]


def _ellipse(n: int, a: float, b: float, centre: tuple[float, float], angle: float) -> list:
    c, s = math.cos(angle), math.sin(angle)
    pts = []
    for k in range(n):
        t = 2 * math.pi * k / n
        x, y = a * math.cos(t), b * math.sin(t)
        pts.append((centre[0] + c * x - s * y, centre[1] + s * x + c * y))
    return pts


def _rect(x0: float, y0: float, x1: float, y1: float) -> list:
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def _annulus(n: int, r_in: float, r_out: float, a0: float = 0.0, a1: float = 2 * math.pi) -> list[list]:
    """Convex trapezoids that tile the annulus sector from angle a0 to a1."""
    angles = np.linspace(a0, a1, n + 1)
    return [
        [
            (r_in * math.cos(t0), r_in * math.sin(t0)),
            (r_out * math.cos(t0), r_out * math.sin(t0)),
            (r_out * math.cos(t1), r_out * math.sin(t1)),
            (r_in * math.cos(t1), r_in * math.sin(t1)),
        ]
        for t0, t1 in zip(angles[:-1], angles[1:], strict=True)
    ]


def _star(points: int, r_out: float, r_in: float) -> list[list]:
    """A star as its inner polygon plus one triangle per point (point up)."""
    inner = _regular(points, r_in, phase=math.pi / 2 + math.pi / points)
    tips = _regular(points, r_out, phase=math.pi / 2)
    pieces = [inner]
    for k in range(points):
        pieces.append([inner[k - 1], tips[k], inner[k]])
    return pieces


def _heart() -> list[list]:
    lobes = [_regular(16, 1.6, (-1.35, 1.0)), _regular(16, 1.6, (1.35, 1.0))]
    return [*lobes, [(-2.85, 0.55), (0.0, -3.0), (2.85, 0.55), (0.0, 1.6)]]


# Outlines in centimetres. Shapes with 2*pi symmetry are re-centred on their bounding box afterwards.
_OUTLINES_CM: list[tuple[str, str, list[list], float]] = [
    (
        "R",
        "letter R",
        [
            _rect(0, 0, 1.4, 6),
            _rect(1.4, 4.8, 3.2, 6),
            _rect(1.4, 3, 3.2, 4.2),
            [(3.2, 3), (3.6, 3), (4.6, 4), (4.6, 5), (3.6, 6), (3.2, 6)],
            [(2.2, 3), (3.4, 0), (4.9, 0), (3.7, 3)],
        ],
        2 * math.pi,
    ),
    (
        "A",
        "letter A",
        [
            [(0, 0), (1.4, 0), (3.2, 6), (1.8, 6)],
            [(3.6, 0), (5, 0), (3.2, 6), (1.8, 6)],
            [(0.9, 1.5), (4.1, 1.5), (3.75, 2.7), (1.25, 2.7)],
        ],
        2 * math.pi,
    ),
    ("triangle", "triangle", [_regular(3, 3.5, phase=math.pi / 2)], 2 * math.pi / 3),
    ("square", "square", [_rect(-2.5, -2.5, 2.5, 2.5)], math.pi / 2),
    (
        "plus",
        "plus",
        [_rect(-0.95, -3, 0.95, 3), _rect(-3, -0.95, -0.95, 0.95), _rect(0.95, -0.95, 3, 0.95)],
        math.pi / 2,
    ),
    ("T", "letter T", [_rect(0, 4.5, 5.6, 6), _rect(2.0, 0, 3.6, 4.5)], 2 * math.pi),
    ("diamond", "diamond", [[(0, -3), (2.1, 0), (0, 3), (-2.1, 0)]], math.pi),
    ("pentagon", "pentagon", [_regular(5, 3.0, phase=math.pi / 2)], 2 * math.pi / 5),
    ("rectangle", "rectangle", [_rect(-3, -1.6, 3, 1.6)], math.pi),
    (
        "flower",
        "flower",
        [_regular(16, 1.3)]
        + [
            _ellipse(14, 1.7, 1.05, (1.35 * math.cos(a), 1.35 * math.sin(a)), a)
            for a in (0, math.pi / 2, math.pi, 3 * math.pi / 2)
        ],
        math.pi / 2,
    ),
    ("star", "star", _star(5, 3.3, 1.35), 2 * math.pi / 5),
    ("circle", "circle", [_regular(32, 2.8)], 0.0),
    (
        "G",
        "letter G",
        [
            _rect(0, 0, 1.4, 6),
            _rect(1.4, 4.6, 5, 6),
            _rect(1.4, 0, 5, 1.4),
            _rect(3.6, 1.4, 5, 3.2),
            _rect(2.4, 2.2, 3.6, 3.2),
        ],
        2 * math.pi,
    ),
    ("V", "letter V", [[(0, 6), (1.7, 0), (3.3, 0), (1.5, 6)], [(5, 6), (3.5, 6), (1.7, 0), (3.3, 0)]], 2 * math.pi),
    (
        "E",
        "letter E",
        [_rect(0, 0, 1.4, 6), _rect(1.4, 4.6, 4.5, 6), _rect(1.4, 2.35, 4.0, 3.65), _rect(1.4, 0, 4.5, 1.4)],
        2 * math.pi,
    ),
    ("L", "letter L", [_rect(0, 0, 1.5, 6), _rect(1.5, 0, 4.5, 1.5)], 2 * math.pi),
    ("ring", "ring", _annulus(24, 1.8, 3.0), 0.0),
    ("hexagon", "hexagon", [_regular(6, 3.0)], math.pi / 3),
    ("heart", "heart", _heart(), 2 * math.pi),
    (
        "M",
        "letter M",
        [
            _rect(0, 0, 1.3, 6),
            _rect(4.7, 0, 6, 6),
            [(0, 6), (2.4, 1.8), (3.6, 1.8), (1.3, 6)],
            [(6, 6), (4.7, 6), (2.4, 1.8), (3.6, 1.8)],
        ],
        2 * math.pi,
    ),
]


def _make_shapes() -> list[KitShape]:
    out = []
    for name, label, pieces_cm, symmetry in _OUTLINES_CM:
        pieces = [np.asarray(piece, dtype=float) * _CM for piece in pieces_cm]
        if symmetry == 2 * math.pi:
            pts = np.concatenate(pieces)
            centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
            pieces = [piece - centre for piece in pieces]
        out.append(KitShape(name, label, tuple(_ccw(piece) for piece in pieces), symmetry))
    return out


SHAPES: list[KitShape] = _make_shapes()


def split_shapes(mode: str) -> list[int]:
    """Shape indices a scene may use: 0-13 in train, the unseen 14-19 in val and test."""
    return list(TRAIN_SHAPES) if mode == "train" else list(TEST_SHAPES)


def _convex_prism(poly: np.ndarray, z0: float, height: float) -> tuple[list[list[float]], list[tuple[int, int, int]]]:
    """Vertices and outward-facing triangles of a convex CCW polygon extruded from z0 to z0 + height."""
    n = len(poly)
    verts = [[float(x), float(y), z0] for x, y in poly] + [[float(x), float(y), z0 + height] for x, y in poly]
    faces: list[tuple[int, int, int]] = []
    for k in range(1, n - 1):
        faces += [(0, k + 1, k), (n, n + k, n + k + 1)]
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, j + n), (i, j + n, i + n)]
    return verts, faces


def prism_mesh(pieces: list[np.ndarray], z0: float, height: float) -> dict:
    """One mesh part (vertices, faces) holding the extrusions of several convex CCW polygons."""
    verts: list[list[float]] = []
    faces: list[tuple[int, int, int]] = []
    for piece in pieces:
        v, f = _convex_prism(piece, z0, height)
        faces += [(a + len(verts), b + len(verts), c + len(verts)) for a, b, c in f]
        verts += v
    return {"type": "mesh", "vertices": verts, "faces": faces}


def placed_pieces(index: int, xy: tuple[float, float] = (0.0, 0.0), yaw: float = 0.0) -> list[np.ndarray]:
    """The convex pieces of shape ``index`` rotated by ``yaw`` and moved to ``xy``."""
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    return [piece @ rot.T + np.asarray(xy) for piece in SHAPES[index].pieces]


def shape_parts(index: int, height: float = HEIGHT, z0: float = -HEIGHT / 2) -> list[dict]:
    """Parts (for ``shapes.compound``) of shape ``index`` extruded from z0 to z0 + height: one visual
    mesh of the whole outline and one convex collision mesh per piece.

    Few, short URDF elements on purpose: PyBullet fails to parse a compound's one-line URDF once it
    grows past roughly 10,000 characters.
    """
    parts = [{**prism_mesh(list(SHAPES[index].pieces), z0, height), "collide": False}]
    for piece in SHAPES[index].pieces:
        parts.append({**prism_mesh([piece], z0, height), "visual": False})
    return parts


def build_shape(client: int, asset_dir: str, index: int, pose: Pose, color: tuple, mass: float = 0.1) -> int:
    """A graspable kit shape body (origin mid-height at its symmetry centre)."""
    return shapes.compound(client, asset_dir, shape_parts(index), pose, color=color, mass=mass)


class SplitYawOracle(Task):
    """The base oracle, but with the tool rotation folded by the object's symmetry and split evenly
    between pick and place, so that neither tool yaw exceeds 90 degrees.

    The object's final pose is unchanged: the place position does not depend on the pick yaw, and
    the object turns by (place yaw - pick yaw), which is what the demos' rotation label records.
    Tool yaws near +-180 degrees make the wrist joint wrap between +pi and -pi during the 1 mm
    descent moves (``UR5.solve_ik`` wraps joints to (-pi, pi]), which stops the descent.
    """

    def place_pose(self, step: GoalStep, i: int, j: int, pick: Pose) -> Pose:
        """Target j, at the symmetric equivalent of its yaw nearest the object's, composed with the
        inverse grasp-relative object pose (yaw only)."""
        obj = self._pose(step.objects[i])
        obj_yaw = quat_to_yaw(obj[1])
        symmetry = step.symmetries[i] if step.rotations else 0.0  # type: ignore[index]  # set by __post_init__
        yaw = obj_yaw
        if symmetry > 0:
            yaw += math.remainder(quat_to_yaw(step.targets[j][1]) - obj_yaw, symmetry)
        place = multiply((step.targets[j][0], yaw_to_quat(yaw)), invert(multiply(invert(pick), obj)))
        return place[0], yaw_to_quat(quat_to_yaw(place[1]))

    def oracle_act(self, obs: dict | None = None) -> dict | None:
        action = super().oracle_act(obs)
        if action is None:
            return None
        pick, place = action["pose0"], action["pose1"]
        half = math.remainder(quat_to_yaw(place[1]) - quat_to_yaw(pick[1]), 2 * math.pi) / 2
        return {"pose0": (pick[0], yaw_to_quat(-half)), "pose1": (place[0], yaw_to_quat(half))}


OBJECT_FOOTPRINT = (0.08, 0.08, HEIGHT)  # free table area one loose kit shape needs


class ShapeTask(SplitYawOracle):
    """A task with loose kit shapes on the table; remembers each body's shape and colour."""

    def __init__(self, mode: str = "train"):
        super().__init__(mode)
        self.object_shapes: dict[int, int] = {}
        self.object_colors: dict[int, str] = {}

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        self.object_shapes, self.object_colors = {}, {}

    def add_shapes(self, shape_ids: list[int], colors: list[str]) -> list[int]:
        """Scatter one graspable body per shape on free table spots (recorded in ``object_shapes`` /
        ``object_colors`` by body id)."""
        bodies = []
        for shape, color in zip(shape_ids, colors, strict=True):
            pose = self.random_pose(OBJECT_FOOTPRINT)
            if pose is None:
                raise RuntimeError("no room on the table for another kit shape")
            body = self.env.add_object(build_shape(self.env.client, self.env.asset_dir, shape, pose, COLORS[color]))
            self.object_shapes[body], self.object_colors[body] = shape, color
            bodies.append(body)
        return bodies

    def object_half_extents(self, body: int) -> np.ndarray:
        """The kit shape's own-frame box (the base class falls back to the world AABB for mesh bodies,
        which is too large for a rotated shape)."""
        if body in self.object_shapes:
            return SHAPES[self.object_shapes[body]].half_extents
        return super().object_half_extents(body)


__all__ = [
    "SplitYawOracle",
    "ShapeTask",
    "OBJECT_FOOTPRINT",
    "HEIGHT",
    "SHAPES",
    "TEST_SHAPES",
    "TRAIN_SHAPES",
    "KitShape",
    "build_shape",
    "placed_pieces",
    "prism_mesh",
    "shape_parts",
    "split_shapes",
]
