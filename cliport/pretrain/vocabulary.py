"""The words of the pretraining captions, and which captions are true of a crop.

The vocabulary is the tasks': every colour of ``tasks/colors.py`` (the seven CLIPort trains its policies on and
the four its ``-unseen-colors`` splits hold out: :data:`UNSEEN_COLORS`), the 20 kit shapes of
``tasks/kit_shapes.py`` by the names instructions use ("letter R", "star"), blocks, bowls, the everyday objects
of ``tasks/packing_object_set.py`` and the spatial words of the tasks ("left", "right", "top", "bottom": smaller y,
larger y, smaller x, larger x, as :func:`cliport.tasks.assembling_kits.spatial_word` uses them).

A thing in a crop is a :class:`Thing` (what a caption can say of an object); a caption names one thing, with or
without its colour, or two things and how they lie. Captions are compared through keys: :func:`thing_key`
(``"red:block"``, ``"*:block"`` for a caption that leaves the colour out) and :func:`relation_key`. A crop's
:func:`crop_facts` are the keys of every caption true of it, so a caption is true of a crop exactly when its key is
among the crop's facts; the contrastive loss counts every true caption of a batch as a positive.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.tasks.colors import COLORS, TRAIN_COLORS

#: The colours a caption can name, in tasks/colors.py's order.
COLOR_NAMES: tuple[str, ...] = tuple(COLORS)
#: The colours CLIPort's ``-unseen-colors`` splits hold out of every training demo: orange, purple, pink, white.
UNSEEN_COLORS: tuple[str, ...] = tuple(c for c in COLORS if c not in TRAIN_COLORS)
#: The kinds of object a scene holds (a kit shape's noun is its label, an everyday object's its name).
KINDS = ("block", "bowl", "shape", "object")
#: Relations of two things in a top-down crop: the tasks' spatial words, by axis (see the module docstring).
RELATIONS = ("left of", "right of", "above", "below")
#: How much longer one axis of two things' offset must be than the other for a relation to be said of them.
RELATION_DOMINANCE = 1.5
#: A caption that names a thing with a colour leaves the colour out this often (kit shapes, blocks, bowls).
NO_COLOR_RATE = 0.2

_THING_TEMPLATES = ("a {}", "the {}", "{}", "a photo of a {}", "there is a {}")
_RELATION_TEMPLATES = ("the {} {} the {}", "a {} {} a {}")


@dataclass(frozen=True)
class Thing:
    """What a caption can say of one object: its ``kind`` (:data:`KINDS`), its ``noun`` ("block", "bowl", a kit
    shape's label such as "letter R", an everyday object's name) and its ``color`` (None: an everyday object,
    whose colour is its own and never named)."""

    kind: str
    noun: str
    color: str | None

    def to_list(self) -> list[Any]:
        """``[kind, noun, color]``: how crop metadata stores it (JSON)."""
        return [self.kind, self.noun, self.color]

    @classmethod
    def from_list(cls, value: list[Any]) -> Thing:
        kind, noun, color = value
        return cls(str(kind), str(noun), None if color is None else str(color))


def thing_key(thing: Thing, with_color: bool = True) -> str:
    """``"red:block"``; ``"*:block"`` without the colour (and always for things without one)."""
    color = thing.color if with_color and thing.color is not None else "*"
    return f"{color}:{thing.noun}"


def relation_key(a: Thing, relation: str, b: Thing) -> str:
    """The key of a caption saying that ``a`` lies ``relation`` ``b`` (both named with their colours)."""
    return f"{thing_key(a)}|{relation}|{thing_key(b)}"


def relation_of(a_xy: tuple[float, float], b_xy: tuple[float, float]) -> str | None:
    """How a thing at world ``a_xy`` lies relative to one at ``b_xy`` (m), or None when neither axis dominates.

    y decides left / right and x above / below (the tasks' 'left' is the smaller y, 'top' the smaller x), when
    that axis's offset is at least :data:`RELATION_DOMINANCE` times the other's.
    """
    dx, dy = a_xy[0] - b_xy[0], a_xy[1] - b_xy[1]
    if abs(dy) >= RELATION_DOMINANCE * abs(dx) and dy != 0:
        return "left of" if dy < 0 else "right of"
    if abs(dx) >= RELATION_DOMINANCE * abs(dy) and dx != 0:
        return "above" if dx < 0 else "below"
    return None


def crop_facts(things: list[Thing], positions: list[tuple[float, float]] | None = None) -> set[str]:
    """The keys of every caption true of a crop that shows ``things``: each with and without its colour, and, for
    a top-down crop (``positions``: each thing's world xy, m), each ordered pair's relation where one is said."""
    facts = {thing_key(t, with_color) for t in things for with_color in (True, False)}
    if positions is not None:
        for i, (a, a_xy) in enumerate(zip(things, positions, strict=True)):
            for j, (b, b_xy) in enumerate(zip(things, positions, strict=True)):
                relation = relation_of(a_xy, b_xy) if i != j else None
                if relation is not None:
                    facts.add(relation_key(a, relation, b))
    return facts


def article(phrase: str) -> str:
    """``"an"`` before a vowel ("an orange block"), else ``"a"``."""
    return "an" if phrase[:1] in "aeiou" else "a"


def thing_phrase(thing: Thing, with_color: bool = True) -> str:
    """``"red block"``, ``"white letter R"``, ``"rubber duck"`` (no colour for things without one)."""
    if with_color and thing.color is not None:
        return f"{thing.color} {thing.noun}"
    return thing.noun


def _with_article(template: str, phrase: str) -> str:
    return template.replace("a {}", f"{article(phrase)} {{}}").format(phrase)


def thing_caption(thing: Thing, rng: np.random.Generator) -> tuple[str, str]:
    """A caption naming ``thing`` (a random template; the colour left out at :data:`NO_COLOR_RATE`) and its key."""
    with_color = thing.color is not None and rng.random() >= NO_COLOR_RATE
    phrase = thing_phrase(thing, with_color)
    template = _THING_TEMPLATES[int(rng.integers(len(_THING_TEMPLATES)))]
    return _with_article(template, phrase), thing_key(thing, with_color)


def relation_caption(a: Thing, relation: str, b: Thing, rng: np.random.Generator) -> tuple[str, str]:
    """A caption saying that ``a`` lies ``relation`` ``b`` ("the red block left of the blue bowl") and its key."""
    template = _RELATION_TEMPLATES[int(rng.integers(len(_RELATION_TEMPLATES)))]
    pa, pb = thing_phrase(a), thing_phrase(b)
    if template.startswith("a "):
        text = f"{article(pa)} {pa} {relation} {article(pb)} {pb}"
    else:
        text = template.format(pa, relation, pb)
    return text, relation_key(a, relation, b)


def probe_color_caption(color: str, noun: str = "block") -> str:
    """The probe's caption of a colour: ``"a red block"``, ``"an orange block"``."""
    phrase = f"{color} {noun}"
    return f"{article(phrase)} {phrase}"


def probe_shape_caption(label: str) -> str:
    """The probe's caption of a kit shape: ``"a letter R"``, ``"an ..."``."""
    return f"{article(label)} {label}"
