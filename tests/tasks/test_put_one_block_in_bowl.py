"""put-one-block-in-bowl-*: three blocks and two bowls of five colours; the instruction names one of each."""

import numpy as np
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.blocks_assets import BOWL_TOLERANCE
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS

UNSEEN_ONLY = [c for c in EVAL_COLORS if c not in TRAIN_COLORS]


@pytest.mark.parametrize(
    "name,mode", [("put-one-block-in-bowl-seen-colors", "test"), ("put-one-block-in-bowl-unseen-colors", "test")]
)
def test_oracle_solves_it_in_one_step(name, mode):
    task = tasks.make(name, mode)
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (10001, 10003):
            episode = run_episode(env, seed, oracle_policy(env))
            assert episode.success and episode.n_actions == 1, seed


def test_the_instruction_names_the_goal_block_and_bowl_among_five_colours():
    task = tasks.make("put-one-block-in-bowl-seen-colors", "train")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (0, 2, 4):
            env.reset(seed)
            assert len(task.block_colors) == 3 and len(task.bowl_colors) == 2
            assert len({*task.block_colors, *task.bowl_colors}) == 5
            assert set(task.block_colors) | set(task.bowl_colors) <= set(TRAIN_COLORS)
            step = task.goals[0]
            block, bowl = task.goal_block, task.goal_bowl
            assert step.objects == [task.block_colors[block]] and step.targets == [task.bowl_colors[bowl]]
            assert task.lang_goal == f"put the {block} block in the {bowl} bowl" == task.instruction_for(block, bowl)
            assert task.max_steps == 2


def test_unseen_variant_uses_unseen_colours_only_in_test_mode():
    for mode, allowed in (("train", TRAIN_COLORS), ("test", EVAL_COLORS)):
        task = tasks.make("put-one-block-in-bowl-unseen-colors", mode)
        with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
            seen = set()
            for seed in range(1, 12, 2):
                env.reset(seed)
                seen |= {*task.block_colors, *task.bowl_colors}
            assert seen <= set(allowed)
            assert bool(seen & set(UNSEEN_ONLY)) == (mode == "test")


def test_an_instruction_naming_an_absent_colour_is_refused():
    task = tasks.make("put-one-block-in-bowl-seen-colors", "train")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(0)
        absent = next(c for c in TRAIN_COLORS if c not in task.block_colors)
        with pytest.raises(ValueError, match=f"no {absent} block"):
            task.instruction_for(absent, next(iter(task.bowl_colors)))


def _near(pose, xy, within):
    return float(np.hypot(pose[0][0] - xy[0], pose[0][1] - xy[1])) < within


def test_instruction_variants_are_the_other_five_pairs_each_with_its_own_oracle_action():
    task = tasks.make("put-one-block-in-bowl-seen-colors", "train")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        obs = env.reset(4)
        goal = task.lang_goal
        variants = task.instruction_variants(obs)
        assert task.lang_goal == goal and len(task.goals) == 1  # the scene's own goal is back
        pairs = [(block, bowl) for block in task.block_colors for bowl in task.bowl_colors]
        others = [pair for pair in pairs if task.instruction_for(*pair) != goal]
        assert [lang for lang, _ in variants] == [task.instruction_for(*pair) for pair in others]
        for (block, bowl), (_, action) in zip(others, variants, strict=True):
            block_xy = task._pose(task.block_colors[block])[0]
            assert _near(action["pose0"], block_xy, 0.025), block  # on the named block (4 cm wide)
            assert _near(action["pose1"], task.bowl_colors[bowl][0], BOWL_TOLERANCE), bowl
        # Recording variants leaves the episode itself as it was (the oracle's random pick pixel included).
        plain = run_episode(env, 4, oracle_policy(env), record=True)
        recorded = run_episode(env, 4, oracle_policy(env), record=True, variants=True)
        assert [s["action"] for s in plain.steps] == [s["action"] for s in recorded.steps]
        assert [lang for lang, _ in recorded.steps[0]["variants"]] == [lang for lang, _ in variants]


def test_a_variant_action_solves_the_scene_it_names():
    task = tasks.make("put-one-block-in-bowl-seen-colors", "train")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        obs = env.reset(2)
        lang, action = task.instruction_variants(obs)[-1]  # another block and another bowl
        block, bowl = lang.split()[2], lang.split()[6]
        assert (block, bowl) != (task.goal_block, task.goal_bowl)
        env.step(action)
        xy = task._pose(task.block_colors[block])[0]
        assert _near((xy, None), task.bowl_colors[bowl][0], BOWL_TOLERANCE)


def test_tasks_without_variants_offer_none():
    assert tasks.with_instruction_variants() == [
        "put-one-block-in-bowl-seen-colors",
        "put-one-block-in-bowl-unseen-colors",
    ]
    task = tasks.make("place-red-in-green")
    assert task.instruction_variants({}) == []
