import re

import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.colors import COLORS, EVAL_COLORS, TRAIN_COLORS

UNSEEN_ONLY = [c for c in EVAL_COLORS if c not in TRAIN_COLORS]


def scene_colors(env) -> set[tuple[int, int, int]]:
    """RGB (0-255) of every visual shape of the task's bodies."""
    out = set()
    for body in env.objects["rigid"] + env.objects["fixed"]:
        for shape in p.getVisualShapeData(body, physicsClientId=env.client):
            out.add(tuple(int(round(c * 255)) for c in shape[7][:3]))
    return out


@pytest.mark.parametrize("name,seed", [("stack-block-pyramid", 0), ("stack-block-pyramid-seq-seen-colors", 2)])
def test_oracle_completes(name, seed):
    task = tasks.make(name)
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env), record=True)
        heights = sorted(
            p.getBasePositionAndOrientation(b, physicsClientId=env.client)[0][2] for b in env.objects["rigid"]
        )
    assert episode.success and episode.done
    assert episode.n_actions == 6
    assert heights == pytest.approx([0.025] * 3 + [0.065] * 2 + [0.105], abs=0.006)
    assert task.lang_goal == "done stacking block pyramid."


def test_rows_share_one_sixth_per_block():
    task = tasks.make("stack-block-pyramid")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(0)
        assert [g.share for g in task.goals] == pytest.approx([1 / 2, 1 / 3, 1 / 6])
        assert task.lang_goal == "make the bottom row with the green, blue and purple blocks"
        bottom = task.goals[0]
        # two bottom blocks in place (in swapped order: any block of the row may take any bottom tile)
        for body, target in zip(bottom.objects[:2], bottom.targets[::-1][:2], strict=True):
            p.resetBasePositionAndOrientation(body, target[0], target[1], physicsClientId=env.client)
        env.settle()
        delta, info = task.reward()
        assert delta == pytest.approx(2 / 6, abs=1e-6) and info["goal_steps_left"] == 3
        body, target = bottom.objects[2], bottom.targets[0]
        p.resetBasePositionAndOrientation(body, target[0], target[1], physicsClientId=env.client)
        env.settle()
        delta, info = task.reward()
        assert delta == pytest.approx(1 / 6, abs=1e-6) and info["goal_steps_left"] == 2
        assert task.lang_goal == "make the middle row with the yellow and orange blocks"


def test_seq_instructions_follow_the_template():
    task = tasks.make("stack-block-pyramid-seq-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(4)
        goals = [g.lang_goal for g in task.goals]
        assert [g.share for g in task.goals] == pytest.approx([1 / 6] * 6)
        assert all(len(g.objects) == 1 for g in task.goals)
    names = [re.match(r"put the (\w+) block on ", g).group(1) for g in goals]
    assert len(set(names)) == 6 and set(names) <= set(TRAIN_COLORS)
    assert goals == [
        f"put the {names[0]} block on the lightest brown block",
        f"put the {names[1]} block on the middle brown block",
        f"put the {names[2]} block on the darkest brown block",
        f"put the {names[3]} block on the {names[0]} and {names[1]} blocks",
        f"put the {names[4]} block on the {names[1]} and {names[2]} blocks",
        f"put the {names[5]} block on the {names[3]} and {names[4]} blocks",
    ]


@pytest.mark.parametrize("variant", ["seen", "unseen"])
def test_train_scenes_never_show_unseen_colors(variant):
    task = tasks.make(f"stack-block-pyramid-seq-{variant}-colors", "train")
    unseen = {COLORS[c] for c in UNSEEN_ONLY}
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (0, 2, 4, 6):
            env.reset(seed)
            assert not scene_colors(env) & unseen
            assert not any(c in g.lang_goal for g in task.goals for c in UNSEEN_ONLY)


def test_unseen_variant_uses_eval_colors_in_test_mode():
    task = tasks.make("stack-block-pyramid-seq-unseen-colors", "test")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        used = set()
        for seed in (10001, 10003):
            env.reset(seed)
            used |= {re.match(r"put the (\w+) block", g.lang_goal).group(1) for g in task.goals}
    assert used <= set(EVAL_COLORS) and used & set(UNSEEN_ONLY)
