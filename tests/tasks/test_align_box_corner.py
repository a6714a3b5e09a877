import math

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import apply, multiply, yaw_to_quat


@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.e2e)])
def test_oracle_completes(seed):
    task = tasks.make("align-box-corner")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env))
    assert episode.success and episode.done
    assert task.lang_goal == "align the brown box with the green corner"


def test_every_symmetric_alternative_counts():
    task = tasks.make("align-box-corner")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(6)
        box = env.objects["rigid"][0]
        step = task.goals[0]
        assert len(step.targets) == 4 and step.matches.all()
        sx, sy, _ = task.object_half_extents(box) * 2
        assert abs(sx - sy) > 1e-3  # seed 6 draws a non-square box, so a plain quarter turn is wrong
        marker_corner = apply(step.targets[0], (sx / 2, sy / 2, 0))
        for target in step.targets:
            p.resetBasePositionAndOrientation(box, target[0], target[1], physicsClientId=env.client)
            assert task.step_reward(step) == pytest.approx(1.0)
            corners = apply(target, [(x * sx / 2, y * sy / 2, 0) for x in (-1, 1) for y in (-1, 1)])
            assert np.min(np.linalg.norm(corners[:, :2] - marker_corner[:2], axis=1)) < 1e-6
        quarter = multiply(step.targets[0], ((0, 0, 0), yaw_to_quat(math.pi / 2)))
        p.resetBasePositionAndOrientation(box, quarter[0], quarter[1], physicsClientId=env.client)
        assert task.step_reward(step) == 0.0
