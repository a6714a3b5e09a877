"""Scenes are a pure function of their seed, and across a training set's seeds they cover every colour (the unseen
ones included), every kit shape and every kind of object."""

from __future__ import annotations

import math

from cliport.env.heightmap import BOUNDS
from cliport.pretrain.scenes import MIN_GAP, OBJECTS_PER_SCENE, make_scene
from cliport.pretrain.vocabulary import COLOR_NAMES, UNSEEN_COLORS
from cliport.tasks.kit_shapes import SHAPES


def test_same_seed_same_scene_other_seed_other_scene() -> None:
    assert make_scene(7) == make_scene(7)
    assert make_scene(7) != make_scene(8)


def test_objects_fit_the_workspace_apart() -> None:
    for seed in range(30):
        objects = make_scene(seed)
        assert OBJECTS_PER_SCENE[0] - 1 <= len(objects) <= OBJECTS_PER_SCENE[1]
        for i, a in enumerate(objects):
            assert BOUNDS[0, 0] + a.radius <= a.xyz[0] <= BOUNDS[0, 1] - a.radius
            assert BOUNDS[1, 0] + a.radius <= a.xyz[1] <= BOUNDS[1, 1] - a.radius
            for b in objects[i + 1 :]:
                assert math.hypot(a.xyz[0] - b.xyz[0], a.xyz[1] - b.xyz[1]) >= a.radius + b.radius + MIN_GAP - 1e-9


def test_the_captions_can_say_every_colour_and_shape() -> None:
    """The first 200 scenes (a quarter of the CPU run's) hold blocks of every colour, the four colours CLIPort's
    unseen-colour demos hold out included, and all 20 kit shapes, the six unseen ones included."""
    things = [o.thing for seed in range(200) for o in make_scene(seed)]
    assert {t.color for t in things if t.kind == "block"} == set(COLOR_NAMES) >= set(UNSEEN_COLORS)
    assert {t.noun for t in things if t.kind == "shape"} == {s.label for s in SHAPES}
    assert {t.kind for t in things} == {"block", "bowl", "shape", "object"}
