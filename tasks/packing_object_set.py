"""The named object set of the packing-objects tasks: object specs, their compound parts and meshes, the
built-in set, a user-supplied set, and the seen/unseen split.

Object set. The reference packing-objects tasks use Google Scanned Objects, which are not available
offline. The built-in set (``builtin_objects()``) has 36 named everyday objects: procedural ones
(soda can, pencil box, ...) made of boxes and cylinders, and meshes shipped with ``pybullet_data``
(rubber duck, teddy bear, lego brick, ...). About two thirds are "seen" (train), the rest "unseen".
Every object is scaled so that its footprint diagonal is at most ~7.5 cm and rests on its widest face.

User-supplied set (to plug in the original objects). Point the environment variable
``CLIPORT_PACKING_OBJECTS`` (or ``load_object_folder(path)``) at a folder in one of two formats:

1. a folder of sub-folders, one per object, named after the object (underscores become spaces)
   and holding one ``.obj`` mesh, e.g. ``my_set/rubber_duck/model.obj``;
2. a folder with a ``objects.json`` manifest::

       {"objects": [{"name": "rubber duck", "mesh": "duck/model.obj",
                     "split": "seen", "size": 0.07, "color": [255, 200, 0]}]}

   ``mesh`` is relative to the manifest's folder; ``split`` ("seen"/"unseen"), ``size`` (footprint
   diagonal in metres, default 0.065) and ``color`` (RGB 0-255) are optional.

Without an explicit split, objects sorted by name are assigned seen, seen, unseen, seen, seen,
unseen, ... Meshes are recentred, turned so that their smallest extent is vertical and scaled; the
collision shape is the mesh's convex hull (PyBullet's default for dynamic meshes).
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.env import shapes
from cliport.env.transforms import Pose, euler_to_quat, quat_to_matrix
from cliport.tasks.colors import COLORS

OBJECTS_ENV_VAR = "CLIPORT_PACKING_OBJECTS"


@dataclass(frozen=True)
class ObjectSpec:
    """A named object: ``make_parts()`` gives its compound parts (body frame, any origin)."""

    name: str
    make_parts: Callable[[], list[dict]]
    color: tuple[float, float, float]
    split: str = "seen"


def _corners(half: np.ndarray) -> np.ndarray:
    return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half


def parts_bounds(parts: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned (lo, hi) of compound parts in the body frame."""
    points = []
    for part in parts:
        kind = part["type"]
        if kind == "box":
            local = _corners(np.asarray(part["size"]) / 2)
        elif kind == "cylinder":
            local = _corners(np.array([part["radius"], part["radius"], part["height"] / 2]))
        elif kind == "sphere":
            local = _corners(np.full(3, part["radius"]))
        else:
            local = np.asarray(part["vertices"], dtype=float)
        rot = quat_to_matrix(euler_to_quat(*part.get("rpy", (0.0, 0.0, 0.0))))
        points.append(local @ rot.T + np.asarray(part.get("position", (0.0, 0.0, 0.0))))
    allp = np.concatenate(points)
    return allp.min(axis=0), allp.max(axis=0)


@functools.lru_cache(maxsize=256)
def centred_parts(spec: ObjectSpec) -> tuple[tuple[dict, ...], tuple[float, float, float]]:
    """The spec's parts shifted so that their bounding box is centred at the origin, and its half extents."""
    parts = spec.make_parts()
    lo, hi = parts_bounds(parts)
    shift = -(lo + hi) / 2
    out = []
    for part in parts:
        part = dict(part)
        part["position"] = tuple(float(c) for c in np.asarray(part.get("position", (0.0, 0.0, 0.0))) + shift)
        out.append(part)
    half = tuple(float(c) for c in (hi - lo) / 2)
    return tuple(out), half  # type: ignore[return-value]  # tuple() of an iterable has no length in its type


def build_object(env: Any, spec: ObjectSpec, pose: Pose, mass: float = 0.05) -> tuple[int, tuple[float, float, float]]:
    """Create a graspable instance of ``spec`` at ``pose`` (its bounding-box centre); returns (body, half extents)."""
    parts, half = centred_parts(spec)
    body = shapes.compound(env.client, env.asset_dir, list(parts), pose, color=spec.color, mass=mass, friction=0.8)
    env.add_object(body, "rigid")
    return body, half


@functools.lru_cache(maxsize=64)
def load_obj(path: str) -> tuple[np.ndarray, tuple[tuple[int, int, int], ...]]:
    """Vertices (N, 3) and triangles of a Wavefront OBJ file (polygons are fanned; groups merged)."""
    vertices: list[list[float]] = []
    faces: list[tuple[int, int, int]] = []
    with open(path, errors="replace") as f:
        for line in f:
            fields = line.split()
            if not fields:
                continue
            if fields[0] == "v":
                vertices.append([float(c) for c in fields[1:4]])
            elif fields[0] == "f":
                idx = [int(t.split("/")[0]) for t in fields[1:]]
                idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
                faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
    if not vertices or not faces:
        raise ValueError(f"{path}: no vertices or faces found")
    return np.asarray(vertices), tuple(faces)


def mesh_parts(path: str, size: float = 0.065) -> list[dict]:
    """Parts of a mesh object: centred, smallest extent turned vertical, footprint diagonal = ``size``."""
    vertices, faces = load_obj(path)
    v = vertices - (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    extent = v.max(axis=0) - v.min(axis=0)
    up = int(np.argmin(extent))
    order = [a for a in range(3) if a != up] + [up]
    v = v[:, order]
    tri = list(faces)
    if order not in ([0, 1, 2], [1, 2, 0], [2, 0, 1]):  # an odd permutation mirrors: keep faces outward
        tri = [(a, c, b) for a, b, c in tri]
    footprint = math.hypot(*(v.max(axis=0) - v.min(axis=0))[:2])
    v = v * (size / footprint)
    return [{"type": "mesh", "vertices": v.tolist(), "faces": tri}]


def _box(sx: float, sy: float, sz: float) -> Callable[[], list[dict]]:
    return lambda: [{"type": "box", "size": (sx, sy, sz)}]


def _cyl(r: float, h: float) -> Callable[[], list[dict]]:
    return lambda: [{"type": "cylinder", "radius": r, "height": h}]


def _spool() -> list[dict]:
    return [
        {"type": "cylinder", "radius": 0.014, "height": 0.04, "position": (0, 0, 0.02)},
        {"type": "cylinder", "radius": 0.022, "height": 0.005, "position": (0, 0, 0.0025)},
        {"type": "cylinder", "radius": 0.022, "height": 0.005, "position": (0, 0, 0.0375)},
    ]


def _stapler() -> list[dict]:
    return [
        {"type": "box", "size": (0.068, 0.024, 0.012), "position": (0, 0, 0.006)},
        {"type": "box", "size": (0.064, 0.02, 0.014), "position": (0.002, 0, 0.019)},
    ]


def _mug() -> list[dict]:
    return [
        {"type": "cylinder", "radius": 0.026, "height": 0.06},
        {"type": "box", "size": (0.014, 0.008, 0.036), "position": (0.032, 0, 0)},
    ]


def _lamp_shade_bucket() -> list[dict]:
    return [
        {"type": "cylinder", "radius": 0.03, "height": 0.05},
        {"type": "cylinder", "radius": 0.033, "height": 0.006, "position": (0, 0, 0.025)},
    ]


def _star(outer: float = 0.034, inner: float = 0.015, points: int = 5) -> list[dict]:
    angles = np.arange(2 * points) * math.pi / points + math.pi / 2
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    poly = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
    return shapes.prism_parts(poly, 0.012)


def _heart() -> list[dict]:
    t = np.linspace(0, 2 * math.pi, 28, endpoint=False)
    x = 16 * np.sin(t) ** 3
    y = 13 * np.cos(t) - 5 * np.cos(2 * t) - 2 * np.cos(3 * t) - np.cos(4 * t)
    return shapes.prism_parts(np.stack([x, y], axis=1) * 0.0019, 0.012)


def _data(rel: str, size: float) -> Callable[[], list[dict]]:
    """The parts of mesh ``rel`` of ``pybullet_data``, which is imported when the parts are made (training from
    recorded demos loads this module through the task registry and needs no simulator)."""

    def make() -> list[dict]:
        import pybullet_data

        return mesh_parts(os.path.join(pybullet_data.getDataPath(), rel), size)

    return make


# (name, parts factory, colour); every third entry is unseen.
_BUILTIN: list[tuple[str, Callable[[], list[dict]], tuple[int, int, int]]] = [
    ("soda can", _cyl(0.03, 0.065), (200, 30, 40)),
    ("pencil box", _box(0.07, 0.03, 0.02), (60, 110, 200)),
    ("rubber duck", _data("duck_vhacd.obj", 0.07), (245, 210, 40)),
    ("tuna can", _cyl(0.034, 0.03), (170, 175, 180)),
    ("eraser", _box(0.05, 0.025, 0.012), (250, 150, 170)),
    ("teddy bear", _data("teddy2_VHACD_CHs.obj", 0.07), (150, 100, 60)),
    ("dice", _box(0.03, 0.03, 0.03), (240, 240, 240)),
    ("toy block", _box(0.04, 0.04, 0.04), (90, 170, 80)),
    ("lego brick", _data("lego/lego.obj", 0.065), (220, 40, 40)),
    ("book", _box(0.065, 0.045, 0.015), (120, 60, 130)),
    ("tissue box", _box(0.06, 0.04, 0.04), (110, 190, 210)),
    ("bunny figurine", _data("bunny.obj", 0.07), (220, 210, 200)),
    ("hockey puck", _cyl(0.034, 0.02), (30, 30, 30)),
    ("candle", _cyl(0.02, 0.06), (250, 240, 210)),
    ("coffee mug", _mug, (240, 240, 235)),
    ("soap bar", _box(0.06, 0.035, 0.02), (250, 200, 220)),
    ("sponge", _box(0.06, 0.04, 0.025), (250, 220, 60)),
    ("jenga block", _data("jenga/jenga.obj", 0.07), (215, 180, 130)),
    ("smartphone", _box(0.065, 0.032, 0.008), (40, 40, 50)),
    ("remote control", _box(0.07, 0.025, 0.015), (70, 70, 80)),
    ("domino", _data("domino/domino.obj", 0.055), (245, 245, 245)),
    ("coaster", _cyl(0.03, 0.006), (160, 110, 70)),
    ("spool of thread", _spool, (60, 160, 200)),
    ("star cookie", _star, (210, 160, 90)),
    ("jar lid", _cyl(0.032, 0.012), (200, 170, 40)),
    ("stapler", _stapler, (180, 30, 30)),
    ("heart magnet", _heart, (230, 60, 110)),
    ("wallet", _box(0.06, 0.045, 0.015), (100, 60, 30)),
    ("cassette tape", _box(0.065, 0.042, 0.012), (60, 60, 60)),
    ("toy donut", _data("torus/torus_textured.obj", 0.065), (230, 150, 170)),
    ("usb stick", _box(0.05, 0.018, 0.008), (30, 90, 170)),
    ("battery", _cyl(0.012, 0.05), (40, 150, 60)),
    ("paint bucket", _lamp_shade_bucket, (80, 120, 180)),
    ("bottle cap", _cyl(0.016, 0.012), (40, 130, 210)),
    ("matchbox", _box(0.05, 0.035, 0.015), (220, 120, 40)),
    ("shape sorter", _data("toys/shape_sorter.obj", 0.07), (230, 100, 40)),
]


def _default_split(index: int) -> str:
    return "unseen" if index % 3 == 2 else "seen"


@functools.lru_cache(maxsize=1)
def builtin_objects() -> tuple[ObjectSpec, ...]:
    """The built-in named object set."""
    return tuple(ObjectSpec(name, make, color, _default_split(k)) for k, (name, make, color) in enumerate(_BUILTIN))


def _color_for(name: str) -> tuple[int, int, int]:
    palette = list(COLORS.values())
    return palette[sum(map(ord, name)) % len(palette)]


def load_object_folder(path: str) -> tuple[ObjectSpec, ...]:
    """A user-supplied object set from a folder (see the module docstring for the two formats)."""
    manifest = os.path.join(path, "objects.json")
    entries: list[dict] = []
    if os.path.exists(manifest):
        with open(manifest) as f:
            for item in json.load(f)["objects"]:
                entries.append({**item, "mesh": os.path.join(path, item["mesh"])})
    else:
        for name in sorted(os.listdir(path)):
            folder = os.path.join(path, name)
            meshes = (
                sorted(m for m in os.listdir(folder) if m.lower().endswith(".obj")) if os.path.isdir(folder) else []
            )
            if meshes:
                entries.append({"name": name.replace("_", " "), "mesh": os.path.join(folder, meshes[0])})
    if not entries:
        raise ValueError(f"{path}: no objects found (expected objects.json or <name>/<mesh>.obj folders)")
    entries.sort(key=lambda e: e["name"])
    specs = []
    for k, e in enumerate(entries):
        split = e.get("split", _default_split(k))
        if split not in ("seen", "unseen"):
            raise ValueError(f"{path}: object {e['name']!r} has split {split!r}; use 'seen' or 'unseen'")
        make = functools.partial(mesh_parts, e["mesh"], float(e.get("size", 0.065)))
        color = tuple(e["color"]) if "color" in e else _color_for(e["name"])
        specs.append(ObjectSpec(e["name"], make, color, split))
    return tuple(specs)


def object_set() -> tuple[ObjectSpec, ...]:
    """The active object set: the folder named by $CLIPORT_PACKING_OBJECTS, else the built-in set."""
    path = os.environ.get(OBJECTS_ENV_VAR)
    return load_object_folder(path) if path else builtin_objects()


def split_objects(specs: tuple[ObjectSpec, ...], mode: str, unseen: bool) -> list[ObjectSpec]:
    """Objects a scene may use: seen ones in train (and everywhere for '-seen-' variants), unseen in
    val/test of '-unseen-' variants."""
    want = "unseen" if unseen and mode in ("val", "test") else "seen"
    return [s for s in specs if s.split == want]
