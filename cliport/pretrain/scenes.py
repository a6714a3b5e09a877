"""Random tabletop scenes for pretraining, as plain data: which objects, of what colour, where. A pure function of
a seed (no simulator), so that the same seed always renders the same crops (:mod:`cliport.pretrain.render`).

A scene holds 4-7 objects at random free spots of the workspace, each one of the tasks' objects: a 4 cm block, a
bowl, a kit shape (any of the 20, seen and unseen) or an everyday object of the built-in packing set, blocks,
bowls and kit shapes in any of the 11 colours (the unseen ones included). Objects keep a gap of at least
:data:`MIN_GAP` between their bounding circles, and two of them are often near enough for a relation crop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cliport.env.heightmap import BOUNDS
from cliport.pretrain.vocabulary import COLOR_NAMES, Thing
from cliport.tasks.blocks_assets import BLOCK, BOWL
from cliport.tasks.kit_shapes import HEIGHT, SHAPES
from cliport.tasks.packing_object_set import builtin_objects, parts_bounds

#: How often each kind of object is drawn (block, bowl, kit shape, everyday object).
KIND_WEIGHTS = {"block": 0.35, "bowl": 0.2, "shape": 0.3, "object": 0.15}
#: Objects per scene: uniform in this range (both ends included).
OBJECTS_PER_SCENE = (4, 7)
#: The least distance (m) between two objects' bounding circles.
MIN_GAP = 0.015
#: Margin (m) between an object's bounding circle and the workspace's edges.
EDGE_MARGIN = 0.03
_PLACEMENT_TRIES = 200


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene: what it is (``thing``), which asset (``index``: the kit shape's or everyday
    object's index; 0 for blocks and bowls), its centre ``xyz`` (m; z where its base rests on the table),
    ``yaw`` (rad), ``radius`` (m) of its footprint's bounding circle and ``height`` (m)."""

    thing: Thing
    index: int
    xyz: tuple[float, float, float]
    yaw: float
    radius: float
    height: float


def _object_size(kind: str, index: int) -> tuple[float, float, float]:
    """(radius of the footprint's bounding circle, height, z of the body origin) of an asset."""
    if kind == "block":
        return math.hypot(BLOCK[0], BLOCK[1]) / 2, BLOCK[2], BLOCK[2] / 2
    if kind == "bowl":
        return BOWL[0] / 2, 0.03, 0.0
    if kind == "shape":
        half = SHAPES[index].half_extents
        return float(math.hypot(half[0], half[1])), HEIGHT, HEIGHT / 2
    spec = builtin_objects()[index]
    lo, hi = parts_bounds(spec.make_parts())
    half = (hi - lo) / 2
    return float(math.hypot(half[0], half[1])), float(2 * half[2]), float(half[2])


def draw_thing(rng: np.random.Generator) -> tuple[Thing, int]:
    """A random object: kind by :data:`KIND_WEIGHTS`, then its colour (any of the 11), kit shape or everyday object."""
    kinds = list(KIND_WEIGHTS)
    weights = np.array([KIND_WEIGHTS[k] for k in kinds])
    kind = kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]
    color = COLOR_NAMES[int(rng.integers(len(COLOR_NAMES)))]
    if kind == "shape":
        index = int(rng.integers(len(SHAPES)))
        return Thing(kind, SHAPES[index].label, color), index
    if kind == "object":
        index = int(rng.integers(len(builtin_objects())))
        return Thing(kind, builtin_objects()[index].name, None), index
    return Thing(kind, kind, color), 0


def make_scene(seed: int) -> list[SceneObject]:
    """The objects of scene ``seed``: the same list for the same seed, on any machine."""
    rng = np.random.default_rng(seed)
    lo, hi = OBJECTS_PER_SCENE
    objects: list[SceneObject] = []
    for _ in range(int(rng.integers(lo, hi + 1))):
        thing, index = draw_thing(rng)
        radius, height, z = _object_size(thing.kind, index)
        for _ in range(_PLACEMENT_TRIES):
            margin = radius + EDGE_MARGIN
            x = float(rng.uniform(BOUNDS[0, 0] + margin, BOUNDS[0, 1] - margin))
            y = float(rng.uniform(BOUNDS[1, 0] + margin, BOUNDS[1, 1] - margin))
            if all(math.hypot(x - o.xyz[0], y - o.xyz[1]) >= radius + o.radius + MIN_GAP for o in objects):
                yaw = float(rng.uniform(0, 2 * math.pi))
                objects.append(SceneObject(thing, index, (x, y, z), yaw, radius, height))
                break
    return objects
