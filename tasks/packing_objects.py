"""packing-{seen,unseen}-objects-{seq,group}: pack named everyday objects into a brown box.

The object set and its seen/unseen split come from ``packing_object_set`` (built-in set, or a user folder
named by $CLIPORT_PACKING_OBJECTS). The container's interior is split into cells (k-d split); a packed
object's target is its cell's centre; the zone metric counts the object's box inside the container.

- "-seq": distinct objects, one per cell; some of them (at least one, not all) are packed one per
  goal step, "pack the {object} in the brown box"; the others are distractors.
- "-group": two or three copies of one object, as many of another kind, and one or two single objects of
  other kinds, as the reference builds it; one goal step, "pack all the {object} objects in the brown box".
Seen variants use seen objects in every mode; unseen variants use unseen objects in val/test.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cliport.env.transforms import at_height, multiply
from cliport.tasks.base import GoalStep
from cliport.tasks.packing_assets import FLOOR_THICKNESS, ZoneOracleMixin, container, kd_split
from cliport.tasks.packing_object_set import ObjectSpec, build_object, centred_parts, object_set, split_objects
from cliport.tasks.registry import register_splits

if TYPE_CHECKING:
    from cliport.env.environment import Environment

CELL_MIN_SIDE = 0.085  # every object's footprint diagonal is below this
WALL_HEIGHT = 0.03


class PackingObjects(ZoneOracleMixin):
    """Shared scene and metric; subclasses choose the objects and the goal steps."""

    unseen = False
    max_steps = 10  # set per episode to targets + 1
    place_yaw_informative = False  # objects are packed without turning (place yaw 0)
    lang_template = None
    done_sentence = "done packing objects."
    interior_range = (0.2, 0.3)

    def reset(self, env: Environment, rng: np.random.Generator) -> None:
        super().reset(env, rng)
        self.half_extents: dict[int, np.ndarray] = {}
        self.names: dict[int, str] = {}  # body id -> object name
        interior = (float(rng.uniform(*self.interior_range)), float(rng.uniform(*self.interior_range)))
        cells = kd_split(rng, interior, CELL_MIN_SIDE)
        pose = self.random_pose((interior[0] + 0.01, interior[1] + 0.01, 0.0), margin=0.01)
        if pose is None:
            raise RuntimeError("no room on the table for the container")
        self.zone_pose = at_height(pose)
        container(env, self.zone_pose, interior, WALL_HEIGHT)
        self.zones = [(self.zone_pose, (interior[0], interior[1], WALL_HEIGHT))]
        self.cells = [multiply(self.zone_pose, ((float(c[0]), float(c[1]), 0.0), (0, 0, 0, 1))) for c, _ in cells]
        self.specs = split_objects(object_set(), self.mode, self.unseen)
        self.build_goals(env, rng)

    def build_goals(self, env: Environment, rng: np.random.Generator) -> None:
        raise NotImplementedError

    def spawn(self, env: Environment, spec: ObjectSpec) -> int | None:
        """Drop an object of ``spec`` on a free table spot; its body id, or None when the table is full."""
        pose = self.random_pose((0.08, 0.08, 0.0), margin=0.005)
        if pose is None:
            return None
        _, half = centred_parts(spec)
        body, _ = build_object(env, spec, at_height(pose, half[2] + 0.001))
        self.half_extents[body] = np.asarray(half)
        self.names[body] = spec.name
        return body

    def target(self, cell: int, body: int) -> tuple:
        """Target pose of ``body`` in cell ``cell``: the cell's centre, resting on the container floor."""
        (x, y, _), quat = self.cells[cell]
        return (x, y, FLOOR_THICKNESS + float(self.half_extents[body][2])), quat

    def object_half_extents(self, body: int) -> np.ndarray:
        """The object's box, known exactly from its parts (the base class would use the first collision
        part or the world AABB, wrong for compound and rotated bodies)."""
        if body in self.half_extents:
            return self.half_extents[body]
        return super().object_half_extents(body)

    def zone_step(self, objects: list[int], targets: list, share: float, lang: str | None = None) -> GoalStep:
        return GoalStep(
            objects=objects,
            matches=np.ones((len(objects), len(targets))),
            targets=targets,
            share=share,
            symmetries=[0.0] * len(objects),
            rotations=False,
            metric="zone",
            zones=self.zones,
            lang_goal=lang,
        )


class PackingObjectsSeq(PackingObjects):
    def build_goals(self, env: Environment, rng: np.random.Generator) -> None:
        n = min(len(self.cells), len(self.specs))
        chosen = [self.specs[int(k)] for k in rng.choice(len(self.specs), n, replace=False)]
        n_pack = int(rng.integers(1, n)) if n > 1 else 1
        bodies = []
        for spec in chosen:
            body = self.spawn(env, spec)
            bodies.append(body)
        self.packable = [(body, k) for k, body in enumerate(bodies) if body is not None]
        steps = []
        for k in range(n_pack):
            body = bodies[k]
            if body is None:
                continue
            lang = f"pack the {chosen[k].name} in the brown box"
            steps.append((body, self.target(k, body), lang))
        for body, target, lang in steps:
            self.add_goal(self.zone_step([body], [target], 1.0 / len(steps), lang))
        self.max_steps = len(steps) + 1

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """Every object on the table, one per step, in a random order: the objects are distinct kinds drawn at
        random, and which of them the instructions name (and how many) is drawn independently of the scene."""
        order = rng.permutation(len(self.packable))
        return [self.zone_step([body], [self.target(k, body)], 1.0) for body, k in (self.packable[i] for i in order)]


class PackingObjectsGroup(PackingObjects):
    """As the reference builds it: two or three copies of the named kind, as many copies of one other kind,
    and one or two single objects of other kinds."""

    def build_goals(self, env: Environment, rng: np.random.Generator) -> None:
        kinds = [self.specs[int(k)] for k in rng.permutation(len(self.specs))]
        n_copies = int(rng.integers(2, min(len(self.cells), 3) + 1)) if len(self.cells) > 1 else 1
        n_singles = int(rng.integers(1, 3))
        self.groups: list[list[int]] = []
        for k, spec in enumerate(kinds[: 2 + n_singles]):
            bodies = [self.spawn(env, spec) for _ in range(n_copies if k < 2 else 1)]
            self.groups.append([b for b in bodies if b is not None])
        copies = self.groups[0]
        targets = [self.target(k, b) for k, b in enumerate(copies)]
        lang = f"pack all the {kinds[0].name} objects in the brown box"
        self.add_goal(self.zone_step(copies, targets, 1.0, lang))
        self.max_steps = len(copies) + 1

    def blind_plan(self, rng: np.random.Generator) -> list[GoalStep]:
        """The two repeated kinds (the named one and its twin distractor kind) in a random order, all copies of
        one packed before the other's: the scene shows both repeated alike, so which one the instruction
        names is a coin flip."""
        candidates = [group for group in self.groups[:2] if group]
        return [
            self.zone_step(group, [self.target(k % len(self.cells), b) for k, b in enumerate(group)], 1.0)
            for group in (candidates[int(k)] for k in rng.permutation(len(candidates)))
        ]


PackingSeenObjectsSeq, PackingUnseenObjectsSeq = register_splits(
    PackingObjectsSeq, "packing-seen-objects-seq", "packing-unseen-objects-seq"
)


PackingSeenObjectsGroup, PackingUnseenObjectsGroup = register_splits(
    PackingObjectsGroup, "packing-seen-objects-group", "packing-unseen-objects-group"
)
