"""The rotation convention end to end: label bin -> decoded place yaw -> the block really turns by theta."""

import math

import numpy as np
import pybullet as p
import pytest

from cliport.agents import make_agent
from cliport.env import shapes
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import quat_to_yaw, yaw_to_quat

N_ROT = 36
AGENT = make_agent("transporter_only", {"width": 0.0625, "n_rotations": N_ROT})


@pytest.mark.parametrize("theta_deg", [30, 120, 250])
def test_label_decode_and_execution_agree(theta_deg):
    theta = math.radians(theta_deg)
    pose0 = np.array([[0.45, 0.1, 0.03, *yaw_to_quat(0.0)]])
    pose1 = np.array([[0.55, -0.1, 0.03, *yaw_to_quat(theta)]])
    k = int(AGENT.action_targets(pose0, pose1, (320, 160))[2])  # the training label
    decoded = AGENT.place.bin_yaw(k)  # what act() turns the argmax bin into (pose1 yaw, pose0 yaw 0)
    assert abs((decoded - theta + math.pi) % (2 * math.pi) - math.pi) <= math.pi / N_ROT + 1e-9
    with Environment(EnvConfig.defaults(camera_scale=0.5)) as env:
        env.reset(0)
        size = (0.08, 0.03, 0.03)  # elongated so that yaw is visible
        block = env.add_object(shapes.box(env.client, size, ((0.45, 0.1, 0.015), (0, 0, 0, 1)), color=(255, 0, 0)))
        env.settle()
        yaw0 = quat_to_yaw(p.getBasePositionAndOrientation(block, physicsClientId=env.client)[1])
        env.step({"pose0": ((0.45, 0.1, 0.03), yaw_to_quat(0.0)), "pose1": ((0.55, -0.1, 0.03), yaw_to_quat(decoded))})
        yaw1 = quat_to_yaw(p.getBasePositionAndOrientation(block, physicsClientId=env.client)[1])
    turned = (yaw1 - yaw0) % (2 * math.pi)
    error = abs((turned - theta + math.pi) % (2 * math.pi) - math.pi)
    assert error <= 2 * math.pi / N_ROT, f"turned {math.degrees(turned):.1f} deg, wanted {theta_deg}"
    assert np.isfinite(turned)
