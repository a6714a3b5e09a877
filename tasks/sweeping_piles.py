"""Pushing piles of small cubes with the spatula: sweeping-piles and separating-piles-{seen,unseen}-colors.

The scene is a pile of 1 cm cubes and one or two 12 cm square zones drawn as visual-only outlines.
The reward is the zone metric over every cube of the pile (a 1 cm cube has one sample point, its
centre), so an episode succeeds only when every cube's centre lies inside the zone.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from cliport.env import shapes
from cliport.env.bullet import p
from cliport.env.primitives import PushSettings
from cliport.env.transforms import Pose, apply, at_height, invert, yaw_to_quat
from cliport.tasks.base import GoalStep, Task
from cliport.tasks.colors import COLORS, split_colors
from cliport.tasks.registry import register, register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

CUBE = (0.01, 0.01, 0.01)
CUBE_MASS = 0.01
N_CUBES = 50
MIN_GAP = 0.015  # centre distance between spawned cubes (a 1 cm cube's diagonal is 1.41 cm)
ZONE = (0.12, 0.12, 0.0)
SQUARE = (0.15, 0.15, 0.0)  # separating-piles squares, as in the reference
MARKER_WIDTH = 0.005
MARKER_HEIGHT = 0.001
BLADE_HALF_WIDTH = 0.025
INNER_MARGIN = 0.01  # cubes closer than this to the zone border are still pushed inward
MOUND_PER_CUBE = 0.003  # length of the mound in front of the 5 cm blade per carried cube (m)
MOUND_FRONT = 0.03  # where the front of the carried mound should stop, past the zone centre (m)
STRAGGLER_DEPTH = 0.015  # how far inside the border a pushed cube must at least end (m)
PRIMITIVE_END_SHORT = 0.05  # the push primitive stops the blade 5 cm short of pose1
PRIMITIVE_START_BACK = 0.02  # ... and starts it 2 cm behind pose0


def square_outline(
    env: Environment,
    pose: Pose,
    size: float,
    color: tuple[float, float, float],
    sides: tuple[str, ...] = ("+x", "-x", "+y", "-y"),
) -> int:
    """A fixed, visual-only square outline of side ``size`` (bars on the named sides) lying on the table."""
    half = size / 2
    bars = {
        "+x": ((half, 0.0), (MARKER_WIDTH, size + MARKER_WIDTH)),
        "-x": ((-half, 0.0), (MARKER_WIDTH, size + MARKER_WIDTH)),
        "+y": ((0.0, half), (size + MARKER_WIDTH, MARKER_WIDTH)),
        "-y": ((0.0, -half), (size + MARKER_WIDTH, MARKER_WIDTH)),
    }
    parts = [
        {
            "type": "box",
            "size": (*bars[s][1], MARKER_HEIGHT),
            "position": (*bars[s][0], MARKER_HEIGHT / 2),
            "collide": False,
        }
        for s in sides
    ]
    body = shapes.compound(env.client, env.asset_dir, parts, at_height(pose), color, mass=0.0)
    return env.add_object(body, "fixed")


def add_pile(
    task: Task, centre: tuple[float, float], spread: float, color: tuple[float, float, float], n: int = N_CUBES
) -> list[int]:
    """Drop ``n`` non-overlapping 1 cm cubes at random spots of a ``spread``-wide square around ``centre``."""
    env, rng = task.env, task.rng
    cubes: list[int] = []
    placed: list[np.ndarray] = []
    while len(cubes) < n:
        xy = np.asarray(centre) + rng.uniform(-spread / 2, spread / 2, size=2)
        if placed and np.min(np.linalg.norm(np.asarray(placed) - xy, axis=1)) < MIN_GAP:
            continue  # overlapping cubes would be pushed apart violently by the solver
        placed.append(xy)
        pose = ((float(xy[0]), float(xy[1]), 0.006), yaw_to_quat(float(rng.uniform(0, 2 * math.pi))))
        cube = shapes.box(env.client, CUBE, pose, color, mass=CUBE_MASS)
        # Resting cubes may sleep: the solver then skips them, which makes each step several times cheaper.
        p.changeDynamics(cube, -1, activationState=p.ACTIVATION_STATE_ENABLE_SLEEPING, physicsClientId=env.client)
        cubes.append(env.add_object(cube))
    return cubes


class PileTask(Task):
    """Shared pusher for pile tasks: the current step's zone metric drives a farthest-cube-first oracle."""

    max_steps = 20
    place_yaw_informative = False  # the spatula's direction comes from the push, not the yaw
    end_effector = "spatula"
    primitive = "push"
    primitive_settings = PushSettings(speed=0.003)

    def zone_local(self, step: GoalStep) -> np.ndarray:
        """Each cube's centre in the frame of the step's first zone, (n, 2)."""
        centres = np.array([self._pose(b)[0] for b in step.objects])
        return apply(invert(step.zones[0][0]), centres)[:, :2]

    def oracle_act(self, obs: dict | None = None) -> dict | None:
        """Push the cube farthest from the zone centre straight toward the centre.

        Cubes outside the zone (by a small inner margin, so that cubes on its border are gathered
        too) are candidates. The blade starts behind the farthest one and carries whatever lies in
        its path; it stops early enough that the mound of carried cubes (about ``MOUND_PER_CUBE``
        long per cube) ends ``MOUND_FRONT`` past the zone centre instead of spilling over the far side.
        """
        if not self.goals:
            return None
        step = self.goals[0]
        zone_pose, zone_size = step.zones[0]
        local = self.zone_local(step)
        half = np.asarray(zone_size[:2]) / 2
        world = np.array([self._pose(b)[0][:2] for b in step.objects])
        bounds = self.env.bounds
        reachable = np.all((world >= bounds[:2, 0]) & (world <= bounds[:2, 1]), axis=1)
        outside = np.any(np.abs(local) > half - INNER_MARGIN, axis=1) & reachable
        if not outside.any():
            outside = np.any(np.abs(local) > half - 0.003, axis=1) & reachable
        if not outside.any():
            return None
        dist = np.where(outside, np.linalg.norm(local, axis=1), -1.0)
        i = int(np.argmax(dist))
        # Work in the zone frame: the push runs from the cube toward the origin.
        start = local[i]
        d = -start / max(float(np.linalg.norm(start)), 1e-9)
        side = np.array([-d[1], d[0]])
        along = (local - start) @ d
        across = (local - start) @ side
        in_path = (along > -0.01) & (along < dist[i] + half[0]) & (np.abs(across) < BLADE_HALF_WIDTH + 0.005)
        carried = int(np.sum(in_path))
        # Blade centre positions along d from the cube: far enough to bring the cube STRAGGLER_DEPTH
        # inside the border (the blade trails the cube centre by 7.5 mm), further if the mound allows.
        inside_at = (1.0 - (half[0] - STRAGGLER_DEPTH) / float(np.max(np.abs(local[i])))) * dist[i]
        stop = max(dist[i] + MOUND_FRONT - MOUND_PER_CUBE * carried, inside_at - 0.0075)
        start = start + side * float(self.rng.uniform(-0.005, 0.005))  # demos stay stochastic
        end = start + d * (stop + PRIMITIVE_END_SHORT)
        quat = (0.0, 0.0, 0.0, 1.0)
        p0, p1 = apply(zone_pose, np.array([[*start, 0.0], [*end, 0.0]]))
        return {"pose0": ((p0[0], p0[1], 0.0), quat), "pose1": ((p1[0], p1[1], 0.0), quat)}


@register("sweeping-piles")
class SweepingPiles(PileTask):
    """Push a pile of 50 small cubes into a 12 cm square zone."""

    lang_template = "push the pile of blocks into the green square"

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        zone_pose = self.random_pose(ZONE)
        assert zone_pose is not None
        zone_pose = at_height(zone_pose)
        square_outline(env, zone_pose, ZONE[0], COLORS["green"])
        cubes = add_pile(self, (0.5, 0.0), 0.2, COLORS["red"])
        self.add_goal(
            GoalStep(
                objects=cubes,
                matches=np.ones((len(cubes), 1)),
                targets=[zone_pose],
                share=1.0,
                metric="zone",
                zones=[(zone_pose, ZONE)],
            )
        )


class SeparatingPiles(PileTask):
    """Push the pile into the 15 cm square of the named colour; a second square distracts (pile and
    squares in three different colours)."""

    unseen = False
    lang_template = None
    done_sentence = "done separating the pile."

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        colors = split_colors(self.mode, self.unseen)
        target_color, other_color, block_color = (colors[int(k)] for k in rng.choice(len(colors), 3, replace=False))
        zones: list[Pose] = []
        for _ in range(1000):
            if len(zones) == 2:
                break
            pose = self.random_pose(SQUARE)
            assert pose is not None
            if zones and np.linalg.norm(np.subtract(pose[0][:2], zones[0][0][:2])) < SQUARE[0] * math.sqrt(2) + 0.02:
                continue  # the two squares must not overlap
            zones.append(at_height(pose))
        square_outline(env, zones[0], SQUARE[0], COLORS[target_color])
        square_outline(env, zones[1], SQUARE[0], COLORS[other_color])
        cubes = add_pile(self, (0.5, 0.0), 0.2, COLORS[block_color])
        self.squares = (cubes, zones)
        self.add_goal(
            self.square_step(zones[0], f"push the pile of {block_color} blocks into the {target_color} square")
        )

    def square_step(self, zone: Pose, lang_goal: str | None = None) -> GoalStep:
        """The goal step of pushing the whole pile into the square at ``zone`` (after ``reset``)."""
        cubes, _ = self.squares
        return GoalStep(
            objects=cubes,
            matches=np.ones((len(cubes), 1)),
            targets=[zone],
            share=1.0,
            metric="zone",
            zones=[(zone, SQUARE)],
            lang_goal=lang_goal,
        )

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """Both squares in a random order, the pile pushed into one, then into the other while the episode
        lasts: which square the instruction names is drawn independently of the scene (the pile is one
        colour, the two squares' colours are both random)."""
        _, zones = self.squares
        return [self.square_step(zones[int(k)]) for k in rng.permutation(len(zones))]


SeparatingPilesSeenColors, SeparatingPilesUnseenColors = register_splits(
    SeparatingPiles, "separating-piles-seen-colors", "separating-piles-unseen-colors"
)
