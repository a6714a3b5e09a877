import math

import numpy as np
import pytest

from cliport.env.environment import EnvConfig, Environment
from cliport.env.robot import JOINT_LIMIT, wrap_near
from cliport.env.transforms import quat_to_yaw, yaw_to_quat


def test_wrap_near_picks_the_closest_whole_turn():
    current = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0])
    q = np.array([0.5, 0.5, 0.1, 0.2, 0.3, -3.0])
    out = wrap_near(q, current)
    assert np.allclose(out[:5], q[:5])  # base and shoulder untouched, others already nearest
    assert out[5] == pytest.approx(2 * math.pi - 3.0)


def test_wrap_near_stays_inside_the_joint_limits():
    current = np.array([0.0, 0.0, 0.0, 0.0, 0.0, JOINT_LIMIT - 0.1])
    out = wrap_near(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3]), current)
    assert -JOINT_LIMIT <= out[5] <= JOINT_LIMIT
    assert math.remainder(out[5] - 0.3, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


@pytest.fixture(scope="module")
def env():
    e = Environment(EnvConfig.defaults(camera_scale=0.5))
    yield e
    e.close()


def test_tool_turns_through_a_full_sweep_without_wrist_flips(env):
    """Yaw steps of 20 degrees turn the wrist by about 20 degrees wherever the IK answer crosses +-180."""
    env.reset(0)
    xyz = (0.5, 0.0, 0.1)
    assert env.robot.movep((xyz, yaw_to_quat(math.radians(-170))))
    for yaw in range(-150, 171, 20):
        before = env.robot.joint_positions()
        target = (xyz, yaw_to_quat(math.radians(yaw)))
        q = env.robot.solve_ik(target)
        assert np.max(np.abs(q - before)) < math.radians(25), yaw
        assert env.robot.movep(target)
        error = math.remainder(quat_to_yaw(env.robot.tip_pose()[1]) - math.radians(yaw), 2 * math.pi)
        assert abs(math.degrees(error)) < 1


def test_home_tool_frame_points_down(env):
    env.reset(0)
    assert np.allclose(np.abs(env.robot.tip_pose()[1]), (0, 0, 0, 1), atol=1e-6)
