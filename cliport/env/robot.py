"""UR5 arm control: inverse kinematics and joint-space motion with budgets in simulation steps."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cliport.env import urdf
from cliport.env.bullet import p
from cliport.env.transforms import Pose

JOINT_LIMIT = 2 * np.pi


def wrap_near(q: np.ndarray, current: np.ndarray) -> np.ndarray:
    """``q`` with joints 2..5 (elbow and wrists) moved by whole turns to the angle nearest ``current``.

    IK answers are only defined up to a full turn of those joints; wrapping to (-pi, pi] instead
    makes the wrist spin almost a full circle when the target crosses +-180 degrees (turning the
    held object with it). The result stays inside the +-2 pi joint limits.
    """
    q = np.array(q, dtype=float)
    near = current[2:] + np.remainder(q[2:] - current[2:] + np.pi, 2 * np.pi) - np.pi
    near = np.where(near > JOINT_LIMIT, near - 2 * np.pi, near)
    q[2:] = np.where(near < -JOINT_LIMIT, near + 2 * np.pi, near)
    return q


class UR5:
    """A UR5 with a suction cup or spatula; joint motion toward IK targets, stepped in simulation."""

    def __init__(self, client: int, end_effector: str, urdf_dir: str, joint_tolerance: float = 1e-3):
        self.client = client
        self.end_effector = end_effector
        path = urdf.write_urdf(urdf.ur5_urdf(end_effector), f"ur5_{end_effector}", urdf_dir)
        self.body = p.loadURDF(path, (0, 0, 0), useFixedBase=True, physicsClientId=client)
        joints = {}
        links = {}
        for i in range(p.getNumJoints(self.body, physicsClientId=client)):
            info = p.getJointInfo(self.body, i, physicsClientId=client)
            joints[info[1].decode()] = i
            links[info[12].decode()] = i
        self.joints = [joints[name] for name in urdf.ARM_JOINTS]
        self.tip_link = links[urdf.TIP_LINK]
        self.tool_frame_link = links["tool_frame"]
        self.home = np.array(urdf.HOME_JOINTS)
        self.joint_tolerance = joint_tolerance
        self.steps_taken = 0  # simulation steps spent moving
        self.on_step: Callable[[], None] | None = None  # called after every motion step (video capture)
        self.reset_joints(self.home)

    def reset_joints(self, q: np.ndarray) -> None:
        for j, qi in zip(self.joints, q, strict=True):
            p.resetJointState(self.body, j, float(qi), physicsClientId=self.client)
        p.setJointMotorControlArray(
            self.body, self.joints, p.POSITION_CONTROL, targetPositions=list(q), physicsClientId=self.client
        )

    def _set_joints(self, q: np.ndarray) -> None:
        """Set joint angles without touching the motors (for virtual poses inside IK)."""
        for j, qi in zip(self.joints, q, strict=True):
            p.resetJointState(self.body, j, float(qi), physicsClientId=self.client)

    def joint_positions(self) -> np.ndarray:
        states = p.getJointStates(self.body, self.joints, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def tool_pose(self) -> Pose:
        """World pose of the tool frame (the point that IK targets)."""
        s = p.getLinkState(self.body, self.tool_frame_link, computeForwardKinematics=True, physicsClientId=self.client)
        return tuple(s[4]), tuple(s[5])

    def tip_pose(self) -> Pose:
        """World pose of the tool tip: 0.12 m past the flange, the contact point."""
        s = p.getLinkState(self.body, self.tip_link, computeForwardKinematics=True, physicsClientId=self.client)
        return tuple(s[4]), tuple(s[5])

    def solve_ik(self, pose: Pose, refinements: int = 5, tolerance: float = 2e-4) -> np.ndarray:
        """Joint angles that put the tool tip at ``pose`` (solved once per move).

        PyBullet's damped-least-squares IK starts from the joint state it finds, so the solve starts
        from the home joints (set only virtually, then restored with their velocities) and stays in
        the home (elbow-up, facing the workspace) family whatever pose the arm is in; the solver's
        null-space variant with joint limits was measured to stop 1-16 mm short, so the plain one
        is used. Near the edge of reach it can stop short, so the solve is repeated from its own
        answer until the tip is within ``tolerance``.
        """
        saved = p.getJointStates(self.body, self.joints, physicsClientId=self.client)
        q = self.home.copy()
        try:
            # Start from the home joints, not the current ones: from some poses the solver otherwise
            # lands in a flipped configuration (base turned a full circle, shoulder over the top) and
            # sweeps the workspace on its way there.
            self._set_joints(self.home)
            for _ in range(refinements):
                q = np.array(
                    p.calculateInverseKinematics(
                        self.body,
                        self.tip_link,
                        targetPosition=pose[0],
                        targetOrientation=pose[1],
                        maxNumIterations=1000,
                        residualThreshold=1e-6,
                        physicsClientId=self.client,
                    )[: len(self.joints)]
                )
                self._set_joints(q)
                if np.linalg.norm(np.subtract(self.tip_pose()[0], pose[0])) < tolerance:
                    break
        finally:
            for j, s in zip(self.joints, saved, strict=True):
                p.resetJointState(self.body, j, s[0], targetVelocity=s[1], physicsClientId=self.client)
        return wrap_near(q, np.array([s[0] for s in saved]))

    def movej(self, target: np.ndarray, speed: float = 0.01, budget: int = 2400) -> bool:
        """Step toward joint target ``target`` by at most ``speed`` rad per step; False if over budget."""
        for _ in range(budget):
            current = self.joint_positions()
            diff = target - current
            if np.all(np.abs(diff) < self.joint_tolerance):
                return True
            norm = float(np.linalg.norm(diff))
            step = current + diff / norm * min(speed, norm)
            p.setJointMotorControlArray(
                self.body,
                self.joints,
                p.POSITION_CONTROL,
                targetPositions=list(step),
                positionGains=[1.0] * len(self.joints),
                physicsClientId=self.client,
            )
            p.stepSimulation(physicsClientId=self.client)
            self.steps_taken += 1
            if self.on_step is not None:
                self.on_step()
        return False

    def movep(self, pose: Pose, speed: float = 0.01, budget: int = 2400) -> bool:
        """Move the tool tip to a world pose (IK once, then joint-space motion)."""
        return self.movej(self.solve_ik(pose), speed, budget)
