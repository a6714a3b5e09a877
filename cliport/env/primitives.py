"""Motion primitives: suction pick-and-place and spatula push, built on the arm's movep."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cliport.env.grippers import Spatula, Suction
from cliport.env.robot import UR5
from cliport.env.transforms import Pose, multiply, yaw_to_quat


@dataclass(frozen=True)
class PickPlaceSettings:
    height: float = 0.32  # lift and carry height above the pick and place poses (m)
    speed: float = 0.01  # joint step per simulation step while lifting, carrying and placing (rad)
    approach_height: float = 0.32  # start above the pick and end above the place this high (m)
    approach_speed: float = 0.01  # joint step while approaching, descending to the pick and retreating (rad)
    descend_step: float = 0.001  # descent per move while looking for contact (m)
    max_descent: float = 0.4  # give up looking for contact after this much descent (m)


def _descend_until_contact(
    robot: UR5, ee: Suction | Spatula, start: Pose, speed: float, settings: PickPlaceSettings
) -> bool:
    """Lower the tool from ``start`` in small moves until the end effector touches something."""
    target = start
    delta = ((0.0, 0.0, -settings.descend_step), (0.0, 0.0, 0.0, 1.0))
    for _ in range(int(settings.max_descent / settings.descend_step)):
        if ee.detect_contact():
            return True
        target = multiply(target, delta)
        if not robot.movep(target, speed, budget=200):
            return ee.detect_contact()
    return ee.detect_contact()


def pick_place(
    robot: UR5, ee: Suction | Spatula, pose0: Pose, pose1: Pose, settings: PickPlaceSettings = PickPlaceSettings()
) -> dict:
    """Pick at ``pose0`` with suction and place at ``pose1``.

    The tool comes down from ``approach_height`` above the pick, lifts the object to ``height``,
    carries it to ``height`` above the place, lowers it until it touches, releases it and rises to
    ``approach_height`` (the rope tasks carry 2 cm high, slowly, but approach and leave from above).
    Returns a dict: ``grasped`` (whether suction held an object after lifting) and ``reached``
    (whether every move finished within its step budget).
    """
    approach = ((0.0, 0.0, settings.approach_height), (0.0, 0.0, 0.0, 1.0))
    carry = ((0.0, 0.0, settings.height), (0.0, 0.0, 0.0, 1.0))
    prepick = multiply(pose0, approach)
    reached = robot.movep(prepick, settings.approach_speed)
    reached &= _descend_until_contact(robot, ee, prepick, settings.approach_speed, settings)
    ee.activate()
    reached &= robot.movep(multiply(pose0, carry), settings.speed)
    grasped = ee.check_grasp()
    if grasped:
        preplace = multiply(pose1, carry)
        reached &= robot.movep(preplace, settings.speed)
        reached &= _descend_until_contact(robot, ee, preplace, settings.speed, settings)
        ee.release()
        reached &= robot.movep(multiply(pose1, approach), settings.approach_speed)
    else:
        ee.release()
        reached &= robot.movep(prepick, settings.approach_speed)
    return {"grasped": grasped, "reached": bool(reached)}


@dataclass(frozen=True)
class PushSettings:
    height: float = 0.31  # approach height (m)
    push_z: float = 0.005  # blade height above the table while pushing (m)
    speed: float = 0.01
    stride: float = 0.01  # distance per move while pushing (m)


def push(robot: UR5, pose0: Pose, pose1: Pose, settings: PushSettings = PushSettings()) -> dict:
    """Push with the spatula from ``pose0`` to ``pose1`` (only their xy matter).

    The blade faces the push direction d (yaw = atan2(d)), starts 2 cm behind the start point and
    stops 5 cm short of the end point, at ``push_z`` above the table.
    """
    p0 = np.array(pose0[0][:2], dtype=float)
    p1 = np.array(pose1[0][:2], dtype=float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length < 1e-6:
        return {"grasped": False, "reached": True}
    d /= length
    start = p0 - 0.02 * d
    end = p1 - 0.05 * d
    quat = yaw_to_quat(float(np.arctan2(d[1], d[0])))
    z = settings.push_z
    reached = robot.movep(((start[0], start[1], settings.height), quat), settings.speed)
    reached &= robot.movep(((start[0], start[1], z), quat), settings.speed)
    n = max(int(np.floor(np.linalg.norm(end - start) / settings.stride)), 1)
    for t in np.linspace(0.0, 1.0, n + 1)[1:]:
        point = start + t * (end - start)
        reached &= robot.movep(((point[0], point[1], z), quat), settings.speed, budget=400)
    reached &= robot.movep(((end[0], end[1], settings.height), quat), settings.speed)
    return {"grasped": False, "reached": bool(reached)}
