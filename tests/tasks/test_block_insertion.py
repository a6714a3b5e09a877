import math

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import multiply, yaw_to_quat


@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.e2e)])
def test_oracle_completes(seed):
    task = tasks.make("block-insertion")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env))
        block = env.objects["rigid"][0]
        z = p.getBasePositionAndOrientation(block, physicsClientId=env.client)[0][2]
    assert episode.success and episode.done
    assert abs(z) < 2e-3, "the block rests on the table inside the slot, not on the fixture"
    assert task.lang_goal == "put the L shape block in the L shape hole"


def test_pose_metric_needs_the_right_yaw():
    task = tasks.make("block-insertion")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(4)
        block = env.objects["rigid"][0]
        target = task.goals[0].targets[0]
        assert task.reward()[0] == 0.0

        def put(pose):
            p.resetBasePositionAndOrientation(block, pose[0], pose[1], physicsClientId=env.client)

        for yaw in (math.pi / 2, math.pi, 3 * math.pi / 2):  # the L has no symmetry: any turn is wrong
            put(multiply(target, ((0, 0, 0.1), yaw_to_quat(yaw))))
            assert task.step_reward(task.goals[0]) == 0.0
        put(multiply(target, ((0.005, 0.005, 0.1), yaw_to_quat(math.radians(10)))))
        delta, info = task.reward()
        assert np.isclose(delta, 1.0) and info["total_reward"] == pytest.approx(1.0)
        assert task.done()
