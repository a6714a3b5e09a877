"""The workcell as a gym-style environment: ``reset(seed)`` and ``step(action)``."""

from __future__ import annotations

import contextlib
import importlib.util
import logging
from typing import Any, Protocol

import numpy as np

from cliport.env import assets, cameras, heightmap, shapes
from cliport.env import config as env_config
from cliport.env.bullet import p
from cliport.env.bullet import quiet_native_output as _quiet_native_output
from cliport.env.config import RENDERER_KINDS, EnvConfig, expected_renderer
from cliport.env.egl import egl_works
from cliport.env.grippers import Spatula, Suction
from cliport.env.primitives import PickPlaceSettings, PushSettings, pick_place, push
from cliport.env.robot import UR5
from cliport.env.transforms import Pose

log = logging.getLogger(__name__)


class ActionError(ValueError):
    """An action that cannot be executed; the message names the offending field."""


class Task(Protocol):
    """What the environment needs from a task (tasks live in ``cliport.tasks``)."""

    max_steps: int
    end_effector: str  # "suction" or "spatula"
    primitive: str  # "pick_place" or "push"
    primitive_settings: PickPlaceSettings | PushSettings

    def reset(self, env: Environment, rng: np.random.Generator) -> None: ...

    def reward(self) -> tuple[float, dict[str, Any]]: ...

    def done(self) -> bool: ...

    @property
    def lang_goal(self) -> str | None: ...


class Environment:
    """PyBullet workcell with a UR5, three RGB-D cameras and an optional task.

    Observations are dicts with ``color`` (320, 160, 3) uint8 and ``height`` (320, 160) float32
    (metres above the table), fused top-down from the three cameras, plus ``cameras`` (a list of
    dicts with ``color`` (H, W, 3) and ``depth`` (H, W)) when raw images are requested.
    Actions are dicts ``{"pose0": (xyz, quat_xyzw), "pose1": (xyz, quat_xyzw)}`` in the world frame.
    """

    bounds = heightmap.BOUNDS
    pixel_size = heightmap.PIXEL_SIZE

    def __init__(self, config: EnvConfig | None = None, task: Task | None = None):
        self.config = config or EnvConfig.defaults()
        if self.config.camera_scale <= 0:
            raise ValueError(f"camera_scale must be positive, got {self.config.camera_scale}")
        self.client = p.connect(p.DIRECT)
        try:
            self.renderer, self.renderer_name = self._choose_renderer(self.config.renderer)
        except Exception:
            p.disconnect(physicsClientId=self.client)
            raise
        self.asset_dir = assets.new_asset_dir()
        #: "egl" or "tiny": recorded in demos and evaluation results (their pixels differ, see docs/workcell.md).
        self.renderer_kind = "egl" if self.renderer == p.ER_BULLET_HARDWARE_OPENGL else "tiny"
        log.info("rendering with %s", self.renderer_name)
        self.camera_configs = [c.scaled(self.config.camera_scale) for c in cameras.realsense_d415()]
        self.task = task
        self.robot: UR5 | None = None
        self.ee: Suction | Spatula | None = None
        self.objects: dict[str, list[int]] = {"fixed": [], "rigid": [], "deformable": []}
        self.steps = 0
        self.seed: int | None = None
        self.frames: list[np.ndarray] | None = None  # video frames while recording
        self._frame_every = 24
        self._frame_camera = self.camera_configs[0]
        self._since_frame = 0

    # ------------------------------------------------------------------ set-up
    def _choose_renderer(self, choice: str) -> tuple[int, str]:
        kind, why = env_config.renderer_choice(choice)
        if kind == "tiny":
            if why.startswith("EGL fails"):
                log.warning("PyBullet's EGL renderer fails on this machine (%s): rendering with TinyRenderer", why)
            return p.ER_TINY_RENDERER, f"cpu (TinyRenderer; {why})" if why else "cpu (TinyRenderer)"
        works, why = egl_works()  # asked for by name: in a child process, as a failing plugin exits its process
        if not works:
            raise RuntimeError(f"renderer='egl' was requested but PyBullet's EGL renderer fails here: {why}")
        spec = importlib.util.find_spec("eglRenderer")
        plugin = -1
        if spec is not None and spec.origin:
            with _quiet_native_output():
                plugin = p.loadPlugin(spec.origin, "_eglRendererPlugin", physicsClientId=self.client)
        if plugin >= 0:
            kind = "GPU" if env_config.gpu_present() else "software OpenGL (Mesa)"
            return p.ER_BULLET_HARDWARE_OPENGL, f"egl ({kind}, PyBullet eglRenderer plugin)"
        if choice == "egl":
            raise RuntimeError("renderer='egl' was requested but PyBullet's eglRenderer plugin did not load")
        return p.ER_TINY_RENDERER, "cpu (TinyRenderer; the EGL plugin did not load)"

    def set_task(self, task: Task | None) -> None:
        self.task = task

    def add_object(self, body: int, category: str = "rigid") -> int:
        """Register a body created in ``self.client``: 'rigid' (graspable), 'fixed' or 'deformable'."""
        if category not in self.objects:
            raise ValueError(f"category must be one of {sorted(self.objects)}, got {category!r}")
        self.objects[category].append(body)
        if category in ("rigid", "deformable") and isinstance(self.ee, Suction):
            self.ee.graspable.add(body)
        return body

    def reset(self, seed: int = 0) -> dict[str, Any]:
        """Rebuild the scene for ``seed`` (same seed, same scene) and return the first observation."""
        p.resetSimulation(physicsClientId=self.client)
        p.setGravity(0, 0, -9.8, physicsClientId=self.client)
        p.setTimeStep(1.0 / self.config.sim_hz, physicsClientId=self.client)
        self.objects = {"fixed": [], "rigid": [], "deformable": []}
        self.steps = 0
        self.seed = seed
        self._build_table()
        end_effector = self.task.end_effector if self.task is not None else "suction"
        self.robot = UR5(self.client, end_effector, self.asset_dir)
        if self.frames is not None:
            self.robot.on_step = self._maybe_capture
        if end_effector == "suction":
            self.ee = Suction(self.client, self.robot.body, self.robot.tip_link, set())
        else:
            self.ee = Spatula(self.client, self.robot.body, self.robot.tip_link)
        if self.task is not None:
            self.task.reset(self, np.random.default_rng(seed))
            self.settle()
        if self.renderer == p.ER_BULLET_HARDWARE_OPENGL:
            # The EGL plugin shades the first frame after a reset differently from every later one
            # (measured); render it once and discard it so that the same seed gives the same pixels.
            self.render_cameras()
        return self.observe()

    def _build_table(self) -> None:
        # The floor is a thick box (a collision-only GEOM_PLANE crashes the EGL plugin) with a tiny
        # hidden visual: it is never inside the heightmap bounds, and drawing it would cost about
        # 45 ms per CPU-rendered camera. The visual-only workspace quad covers the bounds.
        c = self.client
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[2.0, 2.0, 0.05], physicsClientId=c)
        hidden = p.createVisualShape(
            p.GEOM_SPHERE, radius=1e-4, rgbaColor=[0, 0, 0, 0], visualFramePosition=[0, 0, -0.04], physicsClientId=c
        )
        floor = p.createMultiBody(0, col, hidden, [0, 0, -0.051], physicsClientId=c)
        p.changeDynamics(floor, -1, lateralFriction=0.5, physicsClientId=c)
        (x0, x1), (y0, y1) = self.bounds[0], self.bounds[1]
        centre = ((x0 + x1) / 2, (y0 + y1) / 2, -0.0005)
        shapes.box(c, (x1 - x0, y1 - y0, 0.001), (centre, (0, 0, 0, 1)), color=(0.2, 0.2, 0.2), mass=0.0, collide=False)

    # ------------------------------------------------------------------ acting
    def step(self, action: dict[str, Any] | None) -> tuple[dict[str, Any], float, bool, dict[str, Any]]:
        """Execute one primitive; returns (observation, reward, done, info).

        ``info`` holds ``lang_goal`` (the task's current instruction, or None), ``steps``,
        ``grasped``, ``reached`` (the motion finished within its step budgets) and the task's own info.
        """
        if self.robot is None or self.ee is None:
            raise RuntimeError("call reset(seed) before step()")
        motion = {"grasped": False, "reached": True}
        if action is not None:
            pose0, pose1 = validate_action(action, self.bounds)
            primitive = self.task.primitive if self.task is not None else "pick_place"
            if primitive == "push":
                push_settings = self.task.primitive_settings if self.task is not None else PushSettings()
                if not isinstance(push_settings, PushSettings):
                    raise TypeError(f"a push task needs PushSettings, not {type(push_settings).__name__}")
                motion = push(self.robot, pose0, pose1, push_settings)
            else:
                settings = self.task.primitive_settings if self.task is not None else PickPlaceSettings()
                if not isinstance(settings, PickPlaceSettings):
                    raise TypeError(f"a pick-and-place task needs PickPlaceSettings, not {type(settings).__name__}")
                motion = pick_place(self.robot, self.ee, pose0, pose1, settings)
            self.robot.movej(self.robot.home, budget=2400)
        self.settle()
        self.capture_frame()
        self.steps += 1
        reward, task_info = 0.0, dict[str, Any]()
        done = False
        if self.task is not None:
            reward, task_info = self.task.reward()
            done = self.task.done() or self.steps >= self.task.max_steps
        info = {"lang_goal": self.lang_goal, "steps": self.steps, **motion, **task_info}
        return self.observe(), float(reward), bool(done), info

    @property
    def lang_goal(self) -> str | None:
        return self.task.lang_goal if self.task is not None else None

    def settle(self) -> bool:
        """Step until every movable object is slower than ``settle_speed``; False if the cap was hit."""
        bodies = self.objects["rigid"] + self.objects["deformable"]
        for _ in range(self.config.settle_max_steps):
            if all(
                np.linalg.norm(p.getBaseVelocity(b, physicsClientId=self.client)[0]) < self.config.settle_speed
                for b in bodies
            ):
                return True
            p.stepSimulation(physicsClientId=self.client)
        return False

    # ------------------------------------------------------------------ sensing
    def start_recording(self, every: int = 24, scale: float = 0.5) -> None:
        """Capture the front camera every ``every`` simulation steps of arm motion (and after each
        action) into ``self.frames``, at ``scale`` x 640 x 480; for videos of episodes."""
        self.frames = []
        self._frame_every = every
        self._frame_camera = cameras.realsense_d415()[0].scaled(scale)
        self._since_frame = 0
        if self.robot is not None:
            self.robot.on_step = self._maybe_capture

    def stop_recording(self) -> list[np.ndarray]:
        frames, self.frames = self.frames or [], None
        if self.robot is not None:
            self.robot.on_step = None
        return frames

    def capture_frame(self) -> None:
        if self.frames is not None:
            with self._quiet():
                color, _, _ = cameras.render(self._frame_camera, self.client, self.renderer)
            self.frames.append(color)

    def _maybe_capture(self) -> None:
        self._since_frame += 1
        if self._since_frame >= self._frame_every:
            self._since_frame = 0
            self.capture_frame()

    def render_cameras(self) -> list[dict[str, np.ndarray]]:
        """Colour (H, W, 3) uint8 and depth (H, W) float32 from each of the three cameras."""
        return [self.render_camera(cfg) for cfg in self.camera_configs]

    def render_camera(self, config: cameras.CameraConfig) -> dict[str, np.ndarray]:
        """Colour (H, W, 3) uint8 and depth (H, W) float32 from one camera (e.g. ``camera_configs[0]``,
        the front one)."""
        with self._quiet():
            color, depth, _ = cameras.render(config, self.client, self.renderer)
        return {"color": color, "depth": depth}

    def _quiet(self) -> contextlib.AbstractContextManager:
        """The EGL plugin prints a banner on stdout at its first frames; keep it off the console."""
        return _quiet_native_output() if self.renderer == p.ER_BULLET_HARDWARE_OPENGL else contextlib.nullcontext()

    def observe(self, raw_images: bool | None = None) -> dict[str, Any]:
        """The fused top-down observation (and the raw camera images when asked)."""
        images = self.render_cameras()
        views = [(img["color"], img["depth"]) for img in images]
        fused = heightmap.fuse_cameras(views, self.camera_configs, self.bounds, self.pixel_size)
        obs: dict[str, Any] = {"color": fused.color, "height": fused.height}
        if self.config.raw_images if raw_images is None else raw_images:
            obs["cameras"] = images
        return obs

    def render_oracle(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Colour, depth and body-id segmentation from the near-orthographic camera above (task code only)."""
        with self._quiet():
            color, depth, seg = cameras.render(cameras.oracle_camera(), self.client, self.renderer, segmentation=True)
        assert seg is not None
        return color, depth, seg

    def oracle_heightmap(self) -> tuple[np.ndarray, np.ndarray]:
        """Top-down height (320, 160) float32 and body-id map (320, 160) int32 (-1 = nothing) seen
        by the oracle camera: exact object masks for task code and scripted experts, never agents."""
        cfg = cameras.oracle_camera()
        _, depth, seg = self.render_oracle()
        points = heightmap.pointcloud_from_depth(depth, cfg.K)
        points = heightmap.transform_points(points, cameras.camera_rotation(cfg), np.asarray(cfg.position))
        height, ids, seen = heightmap.project_to_heightmap(points, seg, self.bounds, self.pixel_size)
        ids = ids[..., 0]
        ids[~seen] = -1
        return height, ids

    def close(self) -> None:
        if p.isConnected(self.client):
            with _quiet_native_output():
                p.disconnect(self.client)
        assets.remove_asset_dir(self.asset_dir)

    def __enter__(self) -> Environment:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _as_pose(value: Any, name: str) -> Pose:
    try:
        pos, quat = value
        pos = np.asarray(pos, dtype=float)
        quat = np.asarray(quat, dtype=float)
    except (TypeError, ValueError) as e:
        raise ActionError(f"{name} must be a pair (xyz, quat_xyzw), got {value!r}") from e
    if pos.shape != (3,):
        raise ActionError(f"{name} position must have 3 values, got shape {pos.shape}")
    if quat.shape != (4,):
        raise ActionError(f"{name} quaternion must have 4 values (x, y, z, w), got shape {quat.shape}")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
        raise ActionError(f"{name} contains NaN or infinity: {pos.tolist()}, {quat.tolist()}")
    norm = float(np.linalg.norm(quat))
    if norm < 1e-6:
        raise ActionError(f"{name} quaternion has zero length")
    return tuple(pos.tolist()), tuple((quat / norm).tolist())


def validate_action(action: Any, bounds: np.ndarray, margin: float = 0.01) -> tuple[Pose, Pose]:
    """Check an action dict and return its two poses; raise ActionError naming the bad field."""
    if not isinstance(action, dict):
        raise ActionError(f"action must be a dict with 'pose0' and 'pose1', got {type(action).__name__}")
    poses = []
    for name in ("pose0", "pose1"):
        if name not in action:
            raise ActionError(f"action is missing {name!r}")
        pose = _as_pose(action[name], name)
        for axis, value, (lo, hi) in zip("xyz", pose[0], bounds, strict=True):
            hi = hi + (0.1 if axis == "z" else 0.0)  # a held object may be placed on top of a stack
            if not (lo - margin <= value <= hi + margin):
                raise ActionError(f"{name} {axis}={value:.3f} is outside the workspace bounds [{lo:.3f}, {hi:.3f}]")
        poses.append(pose)
    return poses[0], poses[1]


__all__ = ["RENDERER_KINDS", "ActionError", "EnvConfig", "Environment", "Task", "expected_renderer", "validate_action"]
