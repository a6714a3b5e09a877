"""packing-shapes: oracle, zone reward, instruction, splits."""

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import apply
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS
from cliport.tasks.kit_shapes import SHAPES


@pytest.fixture
def env():
    with Environment(EnvConfig.defaults(camera_scale=0.5)) as e:
        yield e


@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.e2e)])
def test_oracle_completes(env, seed):
    task = tasks.make("packing-shapes")
    env.set_task(task)
    episode = run_episode(env, seed, oracle_policy(env), record=True)
    assert episode.success and episode.done and episode.n_actions == 1
    (step,) = episode.steps
    target = next(iter(task.object_shapes.items()))
    assert step["lang_goal"] == f"pack the {SHAPES[target[1]].label} in the brown box"
    assert task.lang_goal == "done packing shapes."


def test_scene_goal_and_zone_reward(env):
    task = tasks.make("packing-shapes")
    env.set_task(task)
    env.reset(4)
    assert len(env.objects["fixed"]) == 1 and len(env.objects["rigid"]) == 5
    assert len(set(task.object_shapes.values())) == 5 and len(set(task.object_colors.values())) == 5
    (step,) = task.goals
    assert step.metric == "zone" and step.objects == [env.objects["rigid"][0]]
    ((zone_pose, zone_size),) = step.zones
    assert 0.1 <= zone_size[0] <= 0.15 and 0.1 <= zone_size[1] <= 0.15
    body = step.objects[0]
    assert task.reward()[0] == 0.0  # the shape starts outside the box
    # Teleported into the box, aligned with it: the full share; half outside: partial credit.
    p.resetBasePositionAndOrientation(body, (*zone_pose[0][:2], 0.012), zone_pose[1], physicsClientId=env.client)
    assert task.zone_fraction(step, body) == 1.0
    half = task.object_half_extents(body)
    np.testing.assert_allclose(half, SHAPES[task.object_shapes[body]].half_extents)
    edge = apply(zone_pose, (zone_size[0] / 2, 0.0, 0.0))
    p.resetBasePositionAndOrientation(body, (edge[0], edge[1], 0.012), zone_pose[1], physicsClientId=env.client)
    assert 0.3 < task.zone_fraction(step, body) < 0.7
    delta, info = task.reward()
    assert 0.3 < delta < 0.7 and info["goal_steps_left"] == 1


def test_splits(env):
    task = tasks.make("packing-shapes", "train")
    env.set_task(task)
    for seed in (0, 2, 4):
        env.reset(seed)
        assert set(task.object_shapes.values()) <= set(range(14))
        assert set(task.object_colors.values()) <= set(TRAIN_COLORS)
    task = tasks.make("packing-shapes", "val")
    env.set_task(task)
    env.reset(1)
    assert set(task.object_shapes.values()) <= set(range(14, 20))
    assert set(task.object_colors.values()) <= set(EVAL_COLORS)
