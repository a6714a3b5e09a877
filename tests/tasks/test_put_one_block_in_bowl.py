"""put-one-block-in-bowl-*: three blocks and two bowls of five colours; the instruction names one of each."""

import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
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
