"""Captions and the facts of a crop: a caption is a positive of a crop exactly when what it says is true of it."""

from __future__ import annotations

import numpy as np

from cliport.pretrain.vocabulary import (
    COLOR_NAMES,
    UNSEEN_COLORS,
    Thing,
    article,
    crop_facts,
    relation_caption,
    relation_of,
    thing_caption,
    thing_key,
)
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS

RED_BLOCK = Thing("block", "block", "red")
BLUE_BOWL = Thing("bowl", "bowl", "blue")
DUCK = Thing("object", "rubber duck", None)


def test_unseen_colours_are_the_ones_the_unseen_splits_hold_out() -> None:
    assert set(UNSEEN_COLORS) == set(EVAL_COLORS) - set(TRAIN_COLORS) == {"orange", "purple", "pink", "white"}
    assert set(COLOR_NAMES) == set(TRAIN_COLORS) | set(EVAL_COLORS)


def test_relations_follow_the_tasks_axes() -> None:
    assert relation_of((0.5, -0.2), (0.5, 0.0)) == "left of"  # smaller y
    assert relation_of((0.5, 0.2), (0.5, 0.0)) == "right of"
    assert relation_of((0.3, 0.0), (0.5, 0.01)) == "above"  # smaller x
    assert relation_of((0.7, 0.0), (0.5, 0.0)) == "below"
    assert relation_of((0.6, 0.1), (0.5, 0.0)) is None  # diagonal: neither axis dominates


def test_facts_hold_what_is_true_and_only_that() -> None:
    facts = crop_facts([RED_BLOCK, BLUE_BOWL], [(0.5, -0.1), (0.5, 0.1)])
    assert {"red:block", "*:block", "blue:bowl", "*:bowl"} <= facts
    assert "red:block|left of|blue:bowl" in facts and "blue:bowl|right of|red:block" in facts
    assert "blue:block" not in facts and "red:block|right of|blue:bowl" not in facts
    assert crop_facts([DUCK]) == {"*:rubber duck"}  # an everyday object's colour is never named
    assert not any("|" in f for f in crop_facts([RED_BLOCK, BLUE_BOWL]))  # oblique crops: no relations


def test_captions_name_their_key_and_every_colour_is_said() -> None:
    rng = np.random.default_rng(0)
    said = set()
    for color in COLOR_NAMES:
        for _ in range(20):
            text, key = thing_caption(Thing("block", "block", color), rng)
            assert key in crop_facts([Thing("block", "block", color)])
            assert ("block" in text) and (color in text) == key.startswith(color)
            said |= {color} if color in text else set()
    assert said == set(COLOR_NAMES)
    text, key = relation_caption(RED_BLOCK, "left of", BLUE_BOWL, rng)
    assert "red block" in text and "left of" in text and "blue bowl" in text and key == "red:block|left of|blue:bowl"
    assert thing_key(DUCK) == "*:rubber duck" and thing_caption(DUCK, rng)[1] == "*:rubber duck"


def test_articles() -> None:
    assert article("orange block") == "an" and article("red block") == "a"
