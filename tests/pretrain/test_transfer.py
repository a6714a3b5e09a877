"""The colour report: the unseen-colours split's test scenes do hold the colours the seen split's demos never show,
and what is measured is split by whether an unseen colour is named."""

from __future__ import annotations

import pytest

from cliport.data.seeds import episode_seeds
from cliport.pretrain.transfer import (
    NAMED_GROUPS,
    colour_report,
    named_colors,
    named_group,
    scene_colors,
    scenes_summary,
    score_by_named,
    split_by_colour,
)
from cliport.pretrain.vocabulary import UNSEEN_COLORS
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS

SEEN_TASK, UNSEEN_TASK = "put-one-block-in-bowl-seen-colors", "put-one-block-in-bowl-unseen-colors"


def test_unseen_test_scenes_use_unseen_colours_and_seen_ones_never() -> None:
    """The first 4 test scenes of each split (the first the lesson tests): the unseen split's colours are CLIPort's
    evaluation palette, nearly every scene holds an unseen colour; the seen split's test scenes hold none."""
    seeds = episode_seeds("test", 4)
    unseen, seen = scene_colors(UNSEEN_TASK, seeds, 0.5), scene_colors(SEEN_TASK, seeds, 0.5)
    unseen_summary, seen_summary = scenes_summary(unseen), scenes_summary(seen)
    assert set(unseen_summary["colors_used"]) <= set(EVAL_COLORS)
    assert set(unseen_summary["unseen_colors_used"]) == set(UNSEEN_COLORS)
    assert unseen_summary["with_an_unseen_color"] == 4  # 5 of 7 colours per scene: at least 2 are unseen
    assert set(seen_summary["colors_used"]) <= set(TRAIN_COLORS) and seen_summary["with_an_unseen_color"] == 0
    for scene in unseen.values():
        assert scene["goal_block"] in scene["blocks"] and scene["goal_bowl"] in scene["bowls"]


def test_split_by_colour_counts_each_episode_and_swap_once() -> None:
    colors = {
        1: {"goal_block": "pink", "goal_bowl": "red", "blocks": ["pink", "red", "blue"], "bowls": ["red", "green"]},
        3: {"goal_block": "blue", "goal_bowl": "green", "blocks": ["blue", "red", "white"], "bowls": ["green", "red"]},
    }
    swaps = [
        {"seed": 1, "named": "red", "followed": True},
        {"seed": 1, "named": "blue", "followed": False},
        {"seed": 3, "named": "white", "followed": True},
        {"seed": 3, "named": "pink", "followed": False},
    ]
    split = split_by_colour({1: True, 3: False}, colors, swaps)
    assert split["unseen_named"] == {"episodes": 1, "solved": 1, "swaps": 2, "followed": 1, "solved_rate": 1.0,
                                     "followed_rate": 0.5}  # fmt: skip
    assert split["seen_named"] == {"episodes": 1, "solved": 0, "swaps": 2, "followed": 1, "solved_rate": 0.0,
                                   "followed_rate": 0.5}  # fmt: skip
    # scene 1 names pink (unseen) and red; scene 3 blue and green: every swap keeps its scene's bowl, seen in both.
    by_named = split["by_named"]
    assert list(by_named) == list(NAMED_GROUPS)
    assert by_named["block_unseen"] == {"episodes": 1, "solved": 1, "swaps": 2, "followed": 1, "solved_rate": 1.0,
                                        "followed_rate": 0.5}  # fmt: skip
    assert by_named["neither_unseen"] == {"episodes": 1, "solved": 0, "swaps": 2, "followed": 1, "solved_rate": 0.0,
                                          "followed_rate": 0.5}  # fmt: skip
    assert by_named["bowl_unseen"]["episodes"] == by_named["both_unseen"]["swaps"] == 0
    assert by_named["bowl_unseen"]["solved_rate"] is None


def test_named_group_says_which_word_is_unseen() -> None:
    assert named_group("pink", "red") == "block_unseen" and named_group("red", "pink") == "bowl_unseen"
    assert named_group("pink", "white") == "both_unseen" and named_group("red", "green") == "neither_unseen"


@pytest.mark.e2e
def test_colour_report_of_an_agent(tmp_path) -> None:
    """A random two-stream agent over cliport-RN-tiny on 2 test scenes of the unseen split: every count adds up."""
    from cliport.agents import make_agent

    agent = make_agent("two_stream", {"clip_weights": "random", "semantic_encoder": "cliport-RN-tiny", "width": 0.0625,
                                      "n_rotations": 1, "map_scale": 0.5})  # fmt: skip
    report = colour_report(agent, UNSEEN_TASK, n_episodes=2, swap_scenes=2, camera_scale=0.5)
    assert report["test"]["episodes"] == 2 and report["following"]["n"] == 4 == len(report["swaps"])
    assert report["unseen_named"]["episodes"] + report["seen_named"]["episodes"] == 2
    assert report["unseen_named"]["swaps"] + report["seen_named"]["swaps"] == 4
    assert sum(part["episodes"] for part in report["by_named"].values()) == 2
    assert sum(part["swaps"] for part in report["by_named"].values()) == 4


def test_named_colours_and_scores_by_what_is_named() -> None:
    assert named_colors("put the pink blocks in a green bowl") == ("pink", "green")
    with pytest.raises(ValueError, match="names no colour"):
        named_colors("stack the blocks")
    episodes = [
        {"seed": 1, "total_reward": 1.0, "actions": 2, "instruction": "put the orange blocks in a blue bowl"},
        {"seed": 2, "total_reward": 0.5, "actions": 2, "instruction": "put the purple blocks in a red bowl"},
        {"seed": 3, "total_reward": 1.0, "actions": 2, "instruction": "put the red blocks in a green bowl"},
    ]
    groups = score_by_named({"episodes": episodes})
    assert groups["block_unseen"]["episodes"] == 2 and groups["block_unseen"]["mean_score"] == 75.0
    assert groups["block_unseen"]["solved"] == 1 and groups["neither_unseen"]["solved"] == 1
    assert groups["both_unseen"] == {"episodes": 0, "mean_score": None, "ci95": None, "solved": 0}
    with pytest.raises(ValueError, match="records no instruction"):
        score_by_named({"episodes": [{"seed": 4, "total_reward": 0.0, "actions": 1}]})
