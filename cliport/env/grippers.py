"""End effectors: the suction cup (constraint-based grasping) and the spatula (pushing)."""

from __future__ import annotations

from cliport.env.bullet import p
from cliport.env.transforms import invert, multiply


class Suction:
    """Suction on the arm's tip link: on contact with a graspable body, freeze the relative pose."""

    def __init__(self, client: int, robot_body: int, tip_link: int, graspable: set[int]):
        self.client = client
        self.robot_body = robot_body
        self.tip_link = tip_link
        self.graspable = graspable  # body ids that may be grasped; shared with the environment
        self.constraint: int | None = None
        self.held: int | None = None

    def activate(self) -> bool:
        """Grasp the graspable body the tip touches, if any. Returns whether a body is held."""
        if self.constraint is not None:
            return True
        contacts = p.getContactPoints(bodyA=self.robot_body, linkIndexA=self.tip_link, physicsClientId=self.client)
        for c in contacts:
            body = c[2]
            if body in self.graspable:
                tip = p.getLinkState(self.robot_body, self.tip_link, physicsClientId=self.client)
                obj = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
                rel = multiply(invert((tip[0], tip[1])), (obj[0], obj[1]))
                self.constraint = p.createConstraint(
                    parentBodyUniqueId=self.robot_body,
                    parentLinkIndex=self.tip_link,
                    childBodyUniqueId=body,
                    childLinkIndex=-1,
                    jointType=p.JOINT_FIXED,
                    jointAxis=(0, 0, 0),
                    parentFramePosition=rel[0],
                    parentFrameOrientation=rel[1],
                    childFramePosition=(0, 0, 0),
                    childFrameOrientation=(0, 0, 0, 1),
                    physicsClientId=self.client,
                )
                self.held = body
                return True
        return False

    def release(self) -> None:
        if self.constraint is not None:
            p.removeConstraint(self.constraint, physicsClientId=self.client)
        self.constraint = None
        self.held = None

    def detect_contact(self) -> bool:
        """While holding: the held body touches something other than the arm; else the tip touches."""
        if self.held is not None:
            contacts = p.getContactPoints(bodyA=self.held, physicsClientId=self.client)
            return any(c[2] != self.robot_body for c in contacts)
        return len(p.getContactPoints(bodyA=self.robot_body, linkIndexA=self.tip_link, physicsClientId=self.client)) > 0

    def check_grasp(self) -> bool:
        return self.held is not None


class Spatula:
    """A rigid blade for pushing; it never grasps."""

    def __init__(self, client: int, robot_body: int, tip_link: int):
        self.client = client
        self.robot_body = robot_body
        self.tip_link = tip_link
        self.held = None

    def activate(self) -> bool:
        return False

    def release(self) -> None:
        pass

    def detect_contact(self) -> bool:
        return len(p.getContactPoints(bodyA=self.robot_body, linkIndexA=self.tip_link, physicsClientId=self.client)) > 0

    def check_grasp(self) -> bool:
        return False
