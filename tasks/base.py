"""Goal machinery shared by every task: goal steps, pose/zone metrics, rewards and the scripted oracle.

A task builds its scene in ``reset`` and appends ``GoalStep``s. ``reward()`` returns the change in
(completed shares + the current step's partial reward) and pops the current step once it is complete, at
most one per call (per action), as the reference banks them; ``done()`` says whether nothing remains.
``oracle_act`` is the scripted expert used for demos.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from cliport.env import heightmap as hm
from cliport.env.bullet import p
from cliport.env.primitives import PickPlaceSettings, PushSettings
from cliport.env.transforms import Pose, apply, invert, multiply, quat_to_yaw, yaw_to_quat

if TYPE_CHECKING:
    from cliport.env.environment import Environment

YAW_TOLERANCE = math.radians(15)
#: A goal step is complete when its reward is within this of its share (the reference's test).
STEP_DONE_TOLERANCE = 0.01


@dataclass
class GoalStep:
    """One step of a task's goal.

    objects: body ids to move; symmetries: each object's yaw symmetry period in radians (0 means
    yaw is ignored, 2*pi means only the identity orientation counts). matches[i, j]: object i may
    go to target j. targets: target poses (the oracle aims at them; the pose metric checks them).
    metric "pose": an object counts when it is within ``tolerance`` (xy) of an allowed target and,
    if ``rotations`` and its symmetry > 0, its folded yaw error is < 15 degrees. metric "zone": the
    fraction of each object's sample points (2 cm grid over its box) inside any of ``zones``
    ((pose, (sx, sy, sz)) boxes; only x and y are checked, and z < ``zone_top`` in the zone's frame
    when that is set). share: this step's part of the episode's total reward (sum 1).
    """

    objects: list[int]
    matches: np.ndarray
    targets: list[Pose]
    share: float
    symmetries: list[float] | None = None
    replace: bool = False
    rotations: bool = False
    metric: str = "pose"
    zones: list[tuple[Pose, tuple[float, float, float]]] = field(default_factory=list)
    tolerance: float = 0.01
    zone_top: float | None = None
    lang_goal: str | None = None

    def __post_init__(self) -> None:
        self.matches = np.asarray(self.matches, dtype=bool).reshape(len(self.objects), len(self.targets))
        if self.symmetries is None:
            self.symmetries = [2 * math.pi] * len(self.objects)
        if self.metric not in ("pose", "zone"):
            raise ValueError(f"metric must be 'pose' or 'zone', got {self.metric!r}")


def folded_yaw_error(yaw_a: float, yaw_b: float, symmetry: float) -> float:
    """|yaw_a - yaw_b| folded by the symmetry period, in [0, symmetry / 2]."""
    err = (yaw_a - yaw_b) % symmetry
    return min(err, symmetry - err)


class Task:
    """Base class of every task. Subclasses set the class attributes and implement ``reset``."""

    name: str = ""
    max_steps: int = 10
    end_effector: str = "suction"
    primitive: str = "pick_place"
    primitive_settings: PickPlaceSettings | PushSettings = PickPlaceSettings()
    lang_template: str | None = None  # fixed instruction of a task without per-step language
    done_sentence: str = "done."
    #: Whether the expert's place yaw carries information: False where no goal checks an object's yaw
    #: (round targets, zones and beads reached without turning), so its place yaw is random or always 0
    #: and one place rotation suffices (``cliport-train`` then defaults to ``--n-rotations 1``).
    place_yaw_informative: bool = True
    #: Whether a scene admits other instructions than the one it was built with, with an oracle for each
    #: (:meth:`instruction_variants`; demos made with ``--every-instruction`` record them).
    offers_instruction_variants: bool = False

    def __init__(self, mode: str = "train"):
        if mode not in ("train", "val", "test"):
            raise ValueError(f"mode must be 'train', 'val' or 'test', got {mode!r}")
        self.mode = mode
        self.goals: list[GoalStep] = []
        self.progress = 0.0
        self._last_total = 0.0
        self.env: Any = None
        self.rng: np.random.Generator = np.random.default_rng(0)

    # ------------------------------------------------------------------ scene
    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        """Build the scene and the goal steps; subclasses call ``super().reset(env, rng)`` first."""
        self.env = env
        self.rng = rng
        self.object_sizes: dict[int, tuple[float, float, float]] = {}
        self.goals = []
        self.progress = 0.0
        self._last_total = 0.0
        self._pursued: GoalStep | None = None

    def random_pose(self, size: tuple[float, float, float], margin: float = 0.0, yaw: bool = True) -> Pose | None:
        """A free pose on the table for an object of footprint ``size``, or None when the table is full.

        Sampled from free (height 0) cells of the oracle heightmap, eroded so that the object's
        bounding circle plus ``margin`` fits; uses the task's seeded generator.
        """
        height, _ = self.env.oracle_heightmap()
        free = (height == 0).astype(np.uint8)
        free[0, :], free[:, 0], free[-1, :], free[:, -1] = 0, 0, 0, 0
        radius = (math.hypot(size[0], size[1]) / 2 + margin) / hm.PIXEL_SIZE
        k = max(int(math.ceil(radius)), 1)
        free = cv2.erode(free, np.ones((2 * k + 1, 2 * k + 1), np.uint8))
        cells = np.argwhere(free > 0)
        if len(cells) == 0:
            return None
        u, v = cells[self.rng.integers(len(cells))]
        x, y, _ = hm.pix_to_xyz((u, v), 0.0)
        theta = float(self.rng.uniform(0, 2 * math.pi)) if yaw else 0.0
        return (x, y, size[2] / 2), yaw_to_quat(theta)

    def add_goal(self, step: GoalStep) -> None:
        self.goals.append(step)

    # ------------------------------------------------------------------ reward
    def _pose(self, body: int) -> Pose:
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.env.client)
        return tuple(pos), tuple(quat)

    def is_match(self, step: GoalStep, i: int, j: int) -> bool:
        """Whether object i of ``step`` sits at target j (pose metric)."""
        pos, quat = self._pose(step.objects[i])
        target = step.targets[j]
        if np.linalg.norm(np.subtract(pos[:2], target[0][:2])) >= step.tolerance:
            return False
        symmetry = step.symmetries[i]  # type: ignore[index]  # GoalStep.__post_init__ sets it
        if step.rotations and symmetry > 0:
            return folded_yaw_error(quat_to_yaw(quat), quat_to_yaw(target[1]), symmetry) < YAW_TOLERANCE
        return True

    def matched_pairs(self, step: GoalStep) -> list[tuple[int, int]]:
        """A maximum set of (object, target) pairs that currently match; targets used once unless replace."""
        ok = np.zeros(step.matches.shape, dtype=bool)
        for i, j in zip(*np.nonzero(step.matches), strict=True):
            ok[i, j] = self.is_match(step, int(i), int(j))
        if step.replace:
            return [(i, int(np.argmax(ok[i]))) for i in range(len(step.objects)) if ok[i].any()]
        owner: dict[int, int] = {}

        def augment(i: int, seen: set[int]) -> bool:
            for j in map(int, np.nonzero(ok[i])[0]):
                if j in seen:
                    continue
                seen.add(j)
                if j not in owner or augment(owner[j], seen):
                    owner[j] = i
                    return True
            return False

        for i in range(len(step.objects)):
            augment(i, set())
        return sorted((i, j) for j, i in owner.items())

    def zone_fraction(self, step: GoalStep, body: int) -> float:
        """Fraction of the body's sample points (2 cm grid over its box, in its own frame) inside any zone."""
        half = self.object_half_extents(body)
        axes = []
        for h in half:
            a = np.arange(-h, h + 1e-9, 0.02)
            axes.append(a - a.mean())
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points = apply(self._pose(body), grid)
        inside = np.zeros(len(points), dtype=bool)
        for zone_pose, zone_size in step.zones:
            local = apply(invert(zone_pose), points)
            within = np.all(np.abs(local[:, :2]) < np.asarray(zone_size[:2]) / 2, axis=1)
            if step.zone_top is not None:
                within &= local[:, 2] < step.zone_top
            inside |= within
        return float(inside.mean())

    def set_object_size(self, body: int, size: tuple[float, float, float]) -> None:
        """Record a body's box size (its own frame) for the zone metric; needed for compound bodies."""
        self.object_sizes[body] = (float(size[0]), float(size[1]), float(size[2]))

    def object_half_extents(self, body: int) -> np.ndarray:
        """Half extents of a body's box in its own frame: the recorded size, else its collision box,
        else its world AABB (too large for rotated or off-centre bodies: record sizes instead)."""
        if body in self.object_sizes:
            return np.asarray(self.object_sizes[body]) / 2
        data = p.getCollisionShapeData(body, -1, physicsClientId=self.env.client)
        if data and data[0][2] == p.GEOM_BOX:
            return np.asarray(data[0][3]) / 2
        lo, hi = p.getAABB(body, physicsClientId=self.env.client)
        return (np.asarray(hi) - np.asarray(lo)) / 2

    def step_reward(self, step: GoalStep) -> float:
        if step.metric == "pose":
            return step.share * len(self.matched_pairs(step)) / len(step.objects)
        fractions = [self.zone_fraction(step, b) for b in step.objects]
        return step.share * float(np.mean(fractions))

    def reward(self) -> tuple[float, dict[str, Any]]:
        """(reward since the last call, info), called once per action.

        As the reference's ``Task.reward()`` banks them: only the current (first) goal step is scored, and it
        is popped and banked once its reward is within 0.01 of its share, so at most one step is completed
        per call. A later step already met is credited only once it is the current one, at a later call.
        """
        current = 0.0
        if self.goals:
            step = self.goals[0]
            current = self.step_reward(step)
            if abs(step.share - current) < STEP_DONE_TOLERANCE:
                self.progress += step.share
                self.goals.pop(0)
                current = 0.0
        total = self.progress + current
        delta = total - self._last_total
        self._last_total = total
        return delta, {"total_reward": total, "goal_steps_left": len(self.goals)}

    def done(self) -> bool:
        return not self.goals or self._last_total > 0.99

    @property
    def lang_goal(self) -> str | None:
        if not self.goals:
            return self.done_sentence if self.lang_template is None else self.lang_template
        return self.goals[0].lang_goal or self.lang_template

    # ------------------------------------------------------------------ oracle
    def oracle_act(self, obs: dict | None = None) -> dict[str, Any] | None:
        """The scripted expert's next action, or None when it cannot find one.

        Among the current step's unmatched objects, the one farthest from its nearest allowed free
        target is picked at a uniformly random pixel of its visible mask (from the oracle camera);
        the place pose is that target composed with the inverse of the grasp-relative object pose
        (yaw only).
        """
        if not self.goals:
            return None
        return self.oracle_act_on(*self.env.oracle_heightmap())

    def oracle_act_on(self, height: np.ndarray, ids: np.ndarray) -> dict[str, Any] | None:
        """:meth:`oracle_act` given the oracle camera's height and body-id maps of the current state."""
        if not self.goals:
            return None
        step = self.goals[0]
        if step.metric == "zone":  # an object wholly inside a zone is done wherever it sits
            done_objects = {i for i, b in enumerate(step.objects) if self.zone_fraction(step, b) >= 1.0}
            taken: set[int] = set()
        else:
            matched = self.matched_pairs(step)
            done_objects = {i for i, _ in matched}
            taken = set() if step.replace else {j for _, j in matched}
        candidates = []
        for i, body in enumerate(step.objects):
            if i in done_objects:
                continue
            free = [j for j in np.nonzero(step.matches[i])[0] if int(j) not in taken]
            if not free:
                continue
            pos = self._pose(body)[0]
            dists = [np.linalg.norm(np.subtract(pos[:2], step.targets[j][0][:2])) for j in free]
            candidates.append((min(dists), i, int(free[int(np.argmin(dists))])))
        for _, i, j in sorted(candidates, reverse=True):
            pick = self.sample_pick(step.objects[i], height, ids)
            if pick is None:
                continue
            return {"pose0": pick, "pose1": self.place_pose(step, i, j, pick)}
        return None

    # ------------------------------------------------------------------ blind expert
    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep] | None:
        """The goal steps that an expert who sees the scene but never reads the instruction pursues, in its
        order; None where the instruction does not change what must be done (that expert is the oracle).

        Called once per episode, right after ``reset``. ``rng`` makes the guesses (seeded per episode,
        apart from the task's own generator): a task whose steps come in a random order, or whose
        instruction names one of several things the scene holds, returns every candidate step that the
        scene leaves possible, shuffled; where the task's rules force an order, it keeps that order. What
        each task returns, and why no blind agent can do better, is in docs/results/blind-ceilings.md.
        """
        return None

    def step_met(self, step: GoalStep) -> bool:
        """Whether ``step``'s reward is within the completion tolerance of its share in the current state."""
        return self.step_reward(step) >= step.share - STEP_DONE_TOLERANCE

    def pursue(self, step: GoalStep) -> dict[str, Any] | None:
        """The oracle's action toward ``step`` from the current state, as if it were the current goal step
        (the task's goals are left as they were); None when the oracle finds none."""
        if step is not self._pursued:
            self.oracle_switch()
            self._pursued = step
        goals, self.goals = self.goals, [step]
        try:
            return self.oracle_act()
        finally:
            self.goals = goals

    def oracle_switch(self) -> None:
        """Forget oracle state kept for the step it was working on (:meth:`pursue` moved to another step)."""

    def rest_action(self) -> dict[str, Any]:
        """An action that moves nothing: pick (or push) at the free table spot farthest from every object
        and put down (or stop) at the same spot. A blind expert with nothing left to do takes it, so that
        steps it has already met are banked one per action."""
        height, _ = self.env.oracle_heightmap()
        free = (height == 0).astype(np.uint8)
        free[0, :], free[:, 0], free[-1, :], free[:, -1] = 0, 0, 0, 0
        distance = cv2.distanceTransform(free, cv2.DIST_L2, 5)
        u, v = np.unravel_index(int(np.argmax(distance)), distance.shape)
        xyz = hm.pix_to_xyz((int(u), int(v)), 0.0)
        pose = ((float(xyz[0]), float(xyz[1]), 0.0), (0.0, 0.0, 0.0, 1.0))
        return {"pose0": pose, "pose1": pose}

    def instruction_variants(self, obs: dict | None = None) -> list[tuple[str, dict[str, Any]]]:
        """Every other instruction this scene admits in its current state, each with the oracle's action for it
        (what :meth:`oracle_act` would do had the scene been built with that instruction). Empty for tasks that
        do not offer them (``offers_instruction_variants``). Leaves the goals and the task's random state as
        they were, so that recording variants does not change the episode."""
        return []

    def sample_pick(self, body: int, height: np.ndarray, ids: np.ndarray) -> Pose | None:
        """A pick pose on a uniformly random pixel of the body's visible mask (eroded by one pixel).

        A body's collision shape may leave gaps its visual shape covers (hanoi rings); if a short
        vertical ray through the drawn pixel does not hit the body first, the nearest pixel whose ray
        does is used instead, so the suction cup lands on something it can hold.
        """
        mask = (ids == body).astype(np.uint8)
        eroded = cv2.erode(mask, np.ones((3, 3), np.uint8))
        if eroded.any():
            mask = eroded
        cells = np.argwhere(mask > 0)
        if len(cells) == 0:
            return None
        drawn = int(self.rng.integers(len(cells)))
        point = hm.pix_to_xyz((int(cells[drawn][0]), int(cells[drawn][1])), height)
        if not self._ray_hits(body, [point])[0]:
            points = [hm.pix_to_xyz((int(u), int(v)), height) for u, v in cells]
            hits = self._ray_hits(body, points)
            if hits.any():
                order = np.argsort(np.linalg.norm(cells - cells[drawn], axis=1), kind="stable")
                point = points[next(k for k in order if hits[k])]
        return point, (0.0, 0.0, 0.0, 1.0)

    def _ray_hits(self, body: int, points: list[tuple[float, float, float]]) -> np.ndarray:
        """Whether a vertical ray from 1 cm above each point down to 2 cm below it hits ``body`` first."""
        starts = [(x, y, z + 0.01) for x, y, z in points]
        ends = [(x, y, z - 0.02) for x, y, z in points]
        hits: list[bool] = []
        for k in range(0, len(points), p.MAX_RAY_INTERSECTION_BATCH_SIZE):
            batch = p.rayTestBatch(
                starts[k : k + p.MAX_RAY_INTERSECTION_BATCH_SIZE],
                ends[k : k + p.MAX_RAY_INTERSECTION_BATCH_SIZE],
                physicsClientId=self.env.client,
            )
            hits.extend(hit[0] == body for hit in batch)
        return np.array(hits, dtype=bool)

    def place_pose(self, step: GoalStep, i: int, j: int, pick: Pose) -> Pose:
        """Target j composed with the inverse grasp-relative pose of object i (yaw only)."""
        obj_pose = self._pose(step.objects[i])
        target = step.targets[j] if step.rotations else (step.targets[j][0], obj_pose[1])
        obj_to_pick = multiply(invert(pick), obj_pose)
        place = multiply(target, invert(obj_to_pick))
        yaw = quat_to_yaw(place[1]) if step.rotations else 0.0
        return place[0], yaw_to_quat(yaw)
