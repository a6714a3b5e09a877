import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.palletizing_boxes import SPAWN_XY, stack_poses


def test_stack_layout_is_three_transposed_layers_of_six():
    poses = stack_poses()
    assert len(poses) == 18
    heights = sorted({round(c[2], 4) for c, _, _ in poses})
    assert len(heights) == 3
    assert [c[2] for c, _, _ in poses] == sorted(c[2] for c, _, _ in poses)  # bottom layer first
    assert {yaw for _, yaw, _ in poses[:6]} != {yaw for _, yaw, _ in poses[6:12]}


def _visible_boxes(env):
    _, ids = env.oracle_heightmap()
    return set(np.unique(ids).tolist()) & set(env.objects["rigid"])


def _at_spawn(env, body):
    xy = p.getBasePositionAndOrientation(body, physicsClientId=env.client)[0][:2]
    return np.linalg.norm(np.subtract(xy, SPAWN_XY)) < 0.03


def test_one_zone_step_per_box_and_boxes_arrive_one_at_a_time():
    task = tasks.make("palletizing-boxes")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(0)
        assert len(task.goals) == 18
        assert all(len(s.objects) == 1 and s.metric == "zone" for s in task.goals)
        assert sum(s.share for s in task.goals) == pytest.approx(1.0)
        first = task.goals[0].objects[0]
        assert _visible_boxes(env) == {first} and _at_spawn(env, first)
        _, reward, _, info = env.step(task.oracle_act())
        assert reward == pytest.approx(1 / 18, abs=1e-6)
        assert info["goal_steps_left"] == 17 and info["spawned"]
        second = task.goals[0].objects[0]
        assert _visible_boxes(env) == {first, second} and _at_spawn(env, second)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 2])
def test_palletizing_oracle_completes(seed):
    task = tasks.make("palletizing-boxes")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env))
    assert episode.success and episode.done
