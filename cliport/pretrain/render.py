"""Renders a pretraining scene (:mod:`cliport.pretrain.scenes`) in the simulator and cuts its crops.

Each object gives two crops and a scene up to :data:`MAX_RELATION_CROPS` more:

- **top**: a square window of the fused top-down colour map the agents see (the workcell's three cameras, fused
  as every observation is; 3.125 mm cells), centred near the object, :data:`WINDOW_M` across (bowls
  :data:`BOWL_WINDOW_M`), so that a 4 cm block spans 6-13 pixels of a 32-pixel model input, as it spans 6-13 cells
  of the agents' maps at map scale 0.5 and 1.
- **oblique**: the object seen by its own camera from a random side, 35-65 degrees above the table, the same
  width of table in view.
- **relation**: a top-down window holding two objects whose offset is mostly along one axis, captioned with
  how they lie ("the red block left of the blue bowl").

A crop records every object whose centre lies in its central :data:`VISIBLE_FRACTION` (its things, for the
captions true of it, :func:`cliport.pretrain.vocabulary.crop_facts`), and for top-down crops their world xy.
Crops are ``crop_px`` square RGB uint8. Beside its crops, a scene gives its whole top-down colour map and which
object each of its pixels shows (:class:`SceneMap`), for the dense objective. Everything random comes from the
scene's seed, so a seed renders the same crops and maps with the same renderer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cliport.env import cameras, heightmap, shapes
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import matrix_to_quat, yaw_to_quat
from cliport.pretrain.scenes import SceneObject, make_scene
from cliport.pretrain.vocabulary import relation_of
from cliport.tasks.blocks_assets import BLOCK
from cliport.tasks.colors import COLORS
from cliport.tasks.kit_shapes import build_shape
from cliport.tasks.packing_object_set import builtin_objects, centred_parts

#: Width (m) of table a crop of a block, kit shape or everyday object shows: uniform in this range.
WINDOW_M = (0.1, 0.22)
#: The same for a bowl (12 cm across).
BOWL_WINDOW_M = (0.16, 0.26)
#: How far (a fraction of the window) a top-down crop's centre may be off its object's, per axis.
JITTER = 0.15
#: Things whose centre lies in this central fraction of a crop (per axis) count as shown by it.
VISIBLE_FRACTION = 0.8
#: At most this many relation crops per scene, of pairs of objects at most :data:`RELATION_DISTANCE_M` apart.
MAX_RELATION_CROPS = 2
RELATION_DISTANCE_M = 0.25
#: A relation crop is at most this wide (m).
RELATION_WINDOW_MAX_M = 0.32
#: Elevation (degrees above the table) and distance (m) of the oblique cameras.
OBLIQUE_ELEVATION_DEG = (35.0, 65.0)
OBLIQUE_DISTANCE_M = (0.35, 0.55)
VIEWS = ("top", "oblique")
#: :attr:`SceneMap.labels` of the table, and of cells that show nothing or the robot (no caption is true of them).
TABLE_LABEL, UNKNOWN_LABEL = 0, 255


@dataclass
class Crop:
    """One crop: ``image`` (crop_px, crop_px, 3) uint8 and its metadata (JSON-ready, see :meth:`meta`)."""

    image: np.ndarray
    view: str  # "top" or "oblique"
    seed: int
    things: list[list[Any]]  # [kind, noun, color] of each thing shown (Thing.to_list), the subject first
    positions: list[list[float]] | None  # world xy (m) of each thing, top-down crops only
    relation: list[Any] | None = None  # [i, "left of", j]: the caption's relation, for relation crops
    window: list[float] | None = None  # [x, y, side] (m): a top-down crop's centre and width on the table

    def meta(self) -> dict[str, Any]:
        """The crop's metadata as stored beside its image: view, seed, things, positions, relation, window."""
        return {
            "view": self.view,
            "seed": self.seed,
            "things": self.things,
            "positions": self.positions,
            "relation": self.relation,
            "window": self.window,
        }


@dataclass
class SceneMap:
    """A scene's fused top-down colour map ``color`` (H, W, 3) uint8, as the agents see it, and ``labels``
    (H, W) uint8: k + 1 where the oracle camera sees the scene's k-th object (``things[k]``), :data:`TABLE_LABEL`
    on the table, :data:`UNKNOWN_LABEL` elsewhere."""

    color: np.ndarray
    labels: np.ndarray
    things: list[list[Any]]  # [kind, noun, color] of each of the scene's objects (Thing.to_list), scene order


def _build(env: Environment, obj: SceneObject) -> int:
    """The object's body in the simulator (static: nothing moves while a scene is rendered)."""
    pose = (obj.xyz, yaw_to_quat(obj.yaw))
    color = COLORS[obj.thing.color] if obj.thing.color is not None else (128, 128, 128)
    if obj.thing.kind == "block":
        return shapes.box(env.client, BLOCK, pose, color, mass=0.0)
    if obj.thing.kind == "bowl":
        return shapes.bowl(env.client, env.asset_dir, pose, color)
    if obj.thing.kind == "shape":
        return build_shape(env.client, env.asset_dir, obj.index, pose, color, mass=0.0)
    spec = builtin_objects()[obj.index]
    parts, _ = centred_parts(spec)
    return shapes.compound(env.client, env.asset_dir, list(parts), pose, color=spec.color, mass=0.0)


def _window(obj: SceneObject, rng: np.random.Generator) -> float:
    low, high = BOWL_WINDOW_M if obj.thing.kind == "bowl" else WINDOW_M
    return float(rng.uniform(low, high))


def _resize(image: np.ndarray, size: int) -> np.ndarray:
    shrink = image.shape[0] > size
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def top_crop(color_map: np.ndarray, centre_xy: tuple[float, float], side_m: float, size: int) -> np.ndarray:
    """A ``side_m`` square of the top-down colour map (rows along y, columns along x) centred on world
    ``centre_xy``, resized to ``size`` pixels; black beyond the map."""
    px = heightmap.PIXEL_SIZE
    side = max(2, int(round(side_m / px)))
    u0 = int(round((centre_xy[1] - heightmap.BOUNDS[1, 0]) / px - side / 2))
    v0 = int(round((centre_xy[0] - heightmap.BOUNDS[0, 0]) / px - side / 2))
    window = np.zeros((side, side, 3), np.uint8)
    rows, cols = color_map.shape[:2]
    r0, r1, c0, c1 = max(u0, 0), min(u0 + side, rows), max(v0, 0), min(v0 + side, cols)
    if r0 < r1 and c0 < c1:
        window[r0 - u0 : r1 - u0, c0 - v0 : c1 - v0] = color_map[r0:r1, c0:c1]
    return _resize(window, size)


def _shown_top(objects: list[SceneObject], centre: tuple[float, float], side_m: float, first: list[int]) -> list[int]:
    """Indices of the objects a top-down window shows, ``first`` leading."""
    half = VISIBLE_FRACTION * side_m / 2
    inside = [
        i
        for i, o in enumerate(objects)
        if abs(o.xyz[0] - centre[0]) <= half and abs(o.xyz[1] - centre[1]) <= half and i not in first
    ]
    return first + inside


def _oblique_camera(obj: SceneObject, side_m: float, size: int, rng: np.random.Generator) -> cameras.CameraConfig:
    """A camera looking at the middle of ``obj`` from a random side and elevation, ``side_m`` of table in view."""
    elevation = math.radians(float(rng.uniform(*OBLIQUE_ELEVATION_DEG)))
    azimuth = float(rng.uniform(0, 2 * math.pi))
    distance = float(rng.uniform(*OBLIQUE_DISTANCE_M))
    target = np.array([obj.xyz[0], obj.xyz[1], obj.height / 2])
    offset = distance * np.array(
        [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]
    )
    eye = target + offset
    forward = -offset / distance
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    focal = size / 2 / (side_m / 2 / distance)
    intrinsics = (focal, 0.0, size / 2, 0.0, focal, size / 2, 0.0, 0.0, 1.0)
    rotation = matrix_to_quat(np.stack([right, down, forward], axis=1))
    position = (float(eye[0]), float(eye[1]), float(eye[2]))
    return cameras.CameraConfig((size, size), intrinsics, position, rotation, zrange=(0.01, 10.0))


def _shown_oblique(objects: list[SceneObject], camera: cameras.CameraConfig, subject: int) -> list[int]:
    """Indices of the objects whose middle projects into the central part of an oblique camera's image."""
    rot = cameras.camera_rotation(camera)
    size = camera.image_size[0]
    half = VISIBLE_FRACTION * size / 2
    shown = [subject]
    for i, o in enumerate(objects):
        if i == subject:
            continue
        point = rot.T @ (np.array([o.xyz[0], o.xyz[1], o.height / 2]) - np.asarray(camera.position))
        if point[2] <= 0:
            continue
        u = camera.K[0, 0] * point[0] / point[2]
        v = camera.K[1, 1] * point[1] / point[2]
        if abs(u) <= half and abs(v) <= half:
            shown.append(i)
    return shown


class SceneRenderer:
    """A workcell without a task that renders pretraining scenes one after another (close it, or use ``with``).

    ``camera_scale``: the workcell cameras' resolution for the top-down map (as the demos'); ``crop_px``: the
    crops' side; ``renderer``: as :class:`~cliport.env.config.EnvConfig`'s (recorded: pixels differ between them).
    """

    def __init__(self, camera_scale: float = 0.5, crop_px: int = 64, renderer: str = "auto") -> None:
        self.env = Environment(EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer))
        self.env.reset(seed=0)  # the table and the robot at home; scenes only add and remove their objects
        ids = self.env.oracle_heightmap()[1]
        self._table = int(np.bincount(ids[ids >= 0]).argmax())  # the workspace's body fills most of the empty map
        self.crop_px = crop_px
        self.renderer_kind = self.env.renderer_kind
        self._bodies: list[int] = []

    def close(self) -> None:
        self.env.close()

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _clear(self) -> None:
        from cliport.env.bullet import p

        for body in self._bodies:
            p.removeBody(body, physicsClientId=self.env.client)
        self._bodies = []

    def render(self, seed: int) -> tuple[list[Crop], SceneMap]:
        """Every crop of scene ``seed`` (top and oblique per object, scene order, then the relation crops) and
        its map."""
        objects = make_scene(seed)
        self._clear()
        self._bodies = [_build(self.env, obj) for obj in objects]
        rng = np.random.default_rng([seed, 1])  # the crops' own stream, apart from the scene's
        images = self.env.render_cameras()
        fused = heightmap.fuse_cameras(
            [(img["color"], img["depth"]) for img in images], self.env.camera_configs, self.env.bounds
        )
        crops = []
        for i, obj in enumerate(objects):
            side = _window(obj, rng)
            centre = (
                obj.xyz[0] + float(rng.uniform(-JITTER, JITTER)) * side,
                obj.xyz[1] + float(rng.uniform(-JITTER, JITTER)) * side,
            )
            shown = _shown_top(objects, centre, side, [i])
            top = self._crop(top_crop(fused.color, centre, side, self.crop_px), "top", seed, objects, shown)
            top.window = [centre[0], centre[1], side]
            crops.append(top)
            camera = _oblique_camera(obj, _window(obj, rng), self.crop_px, rng)
            image = self.env.render_camera(camera)["color"]
            crops.append(self._crop(image, "oblique", seed, objects, _shown_oblique(objects, camera, i), top=False))
        crops += self._relation_crops(fused.color, seed, objects, rng)
        return crops, self._scene_map(fused.color, objects)

    def _scene_map(self, color: np.ndarray, objects: list[SceneObject]) -> SceneMap:
        _, ids = self.env.oracle_heightmap()
        if ids.shape != color.shape[:2]:
            raise ValueError(f"the colour map {color.shape[:2]} and the object ids {ids.shape} differ")
        labels = np.where(ids == self._table, TABLE_LABEL, UNKNOWN_LABEL).astype(np.uint8)
        for k, body in enumerate(self._bodies):
            labels[ids == body] = k + 1
        things = [obj.thing.to_list() for obj in objects]
        return SceneMap(np.ascontiguousarray(color, dtype=np.uint8), labels, things)

    def _crop(
        self, image: np.ndarray, view: str, seed: int, objects: list[SceneObject], shown: list[int], top: bool = True
    ) -> Crop:
        return Crop(
            image=np.ascontiguousarray(image, dtype=np.uint8),
            view=view,
            seed=seed,
            things=[objects[k].thing.to_list() for k in shown],
            positions=[[objects[k].xyz[0], objects[k].xyz[1]] for k in shown] if top else None,
        )

    def _relation_crops(
        self, color_map: np.ndarray, seed: int, objects: list[SceneObject], rng: np.random.Generator
    ) -> list[Crop]:
        pairs = []
        for i, a in enumerate(objects):
            for j in range(i + 1, len(objects)):
                b = objects[j]
                dx, dy = b.xyz[0] - a.xyz[0], b.xyz[1] - a.xyz[1]
                side = max(abs(dx), abs(dy)) + 2 * max(a.radius, b.radius) + 0.03
                if math.hypot(dx, dy) <= RELATION_DISTANCE_M and side <= RELATION_WINDOW_MAX_M:
                    if relation_of(a.xyz[:2], b.xyz[:2]) is not None:
                        pairs.append((i, j, side))
        crops = []
        for k in rng.permutation(len(pairs))[:MAX_RELATION_CROPS]:
            i, j, side = pairs[int(k)]
            if rng.random() < 0.5:
                i, j = j, i
            a, b = objects[i], objects[j]
            centre = ((a.xyz[0] + b.xyz[0]) / 2, (a.xyz[1] + b.xyz[1]) / 2)
            shown = _shown_top(objects, centre, side, [i, j])
            crop = self._crop(top_crop(color_map, centre, side, self.crop_px), "top", seed, objects, shown)
            crop.relation = [0, relation_of(a.xyz[:2], b.xyz[:2]), 1]
            crop.window = [centre[0], centre[1], side]
            crops.append(crop)
        return crops
