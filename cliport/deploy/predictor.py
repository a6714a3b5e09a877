"""Predict one pick-and-place action of a trained run from your own RGB-D cameras (or a fused map)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cliport.deploy.scene import SceneError, check_views, depth_in_metres, fuse_scene, parse_camera
from cliport.env import heightmap as hm
from cliport.env.cameras import CameraConfig
from cliport.errors import ConfigError


def resolve_checkpoint(run_dir: str, which: str = "best") -> tuple[str, int | str]:
    """The checkpoint file of a run (a folder or ``hf://org/name[@revision]``) that ``which`` names (best by
    val.json, last, or a saved step) and its step (or "last")."""
    from cliport.utils.hub import resolve_run_dir
    from cliport.utils.run_dir import RunDir

    run = RunDir(resolve_run_dir(run_dir))
    (step,) = run.resolve(which, run.best_step() if which == "best" else None, allow_all=False)
    return run.checkpoint(step), step


def check_bounds(bounds: Sequence[float] | np.ndarray | None) -> np.ndarray:
    """(3, 2) workspace bounds from 6 numbers x0 x1 y0 y1 z0 z1 (None: the simulator's). The map must keep
    the agents' 320 x 160 cells of 3.125 mm, so the bounds may move but not change size."""
    if bounds is None:
        return hm.BOUNDS.copy()
    b = np.asarray(bounds, dtype=np.float64)
    if b.size != 6 or not np.all(np.isfinite(b)):
        raise ConfigError(f"--bounds must be 6 numbers X0 X1 Y0 Y1 Z0 Z1 (metres), got {list(np.ravel(b))}")
    b = b.reshape(3, 2)
    if np.any(b[:, 1] <= b[:, 0]):
        raise ConfigError(f"--bounds must have X0 < X1, Y0 < Y1 and Z0 < Z1, got {b.ravel().tolist()}")
    want = hm.BOUNDS[:2, 1] - hm.BOUNDS[:2, 0]
    if not np.allclose(b[:2, 1] - b[:2, 0], want, atol=hm.PIXEL_SIZE / 2):
        raise ConfigError(
            f"--bounds must span {want[0]:g} m in x and {want[1]:g} m in y (the {hm.heightmap_shape()[1]} x "
            f"{hm.heightmap_shape()[0]} cells of {hm.PIXEL_SIZE * 1000:g} mm the agents are trained on; move "
            f"the box, keep its size), got {b[0, 1] - b[0, 0]:g} x {b[1, 1] - b[1, 0]:g} m"
        )
    return b


def fuse_views(
    images: Sequence[tuple[np.ndarray, np.ndarray]],
    cameras: Sequence[CameraConfig | dict[str, Any]],
    bounds: np.ndarray = hm.BOUNDS,
    names: Sequence[tuple[str, str]] | None = None,
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Check RGB-D views and fuse them as the simulator does: ({"color" (H, W, 3) uint8, "height" (H, W)
    float32}, notes). ``images``: per camera (rgb (h, w, 3) uint8, depth (h, w) float metres, or integers
    with the camera's depth_scale); ``names``: per camera its (colour, depth) sources for messages."""
    cams = [c if isinstance(c, CameraConfig) else parse_camera(c, i, "cameras") for i, c in enumerate(cameras)]
    check_views(images, cams, names)
    labels = [f"camera {i}" + (f" ({names[i][0]})" if names else "") for i in range(len(cams))]
    views = [
        (np.asarray(color), depth_in_metres(depth, names[i][1] if names else f"image {i}", cams[i], i))
        for i, (color, depth) in enumerate(images)
    ]
    fused, notes = fuse_scene(views, cams, bounds, labels)
    return {"color": fused.color, "height": fused.height}, notes


@dataclass
class Prediction:
    """One predicted action in the robot base frame.

    pick/place: ``xyz`` (metres), ``quat`` (xyzw; pick yaw 0, place yaw = relative yaw), ``pixel`` (u, v)
    in the fused map, and for place ``rotation_bin``. ``obs``: the fused ``color`` (H, W, 3) uint8 and
    ``height`` (H, W) float32 the agent saw; ``act``: the agent's raw ``act()`` result (heatmaps (H, W));
    ``similarity``: its ``similarity_heatmaps`` (``{text: (H, W)}``, empty for agents without them).
    """

    pick: dict[str, Any]
    place: dict[str, Any]
    instruction: str
    checkpoint: str
    obs: dict[str, np.ndarray] = field(repr=False)
    act: dict[str, Any] = field(repr=False)
    notes: list[str] = field(default_factory=list)
    similarity: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        """The JSON object ``cliport-predict`` prints."""
        return {
            "pick": self.pick,
            "place": self.place,
            "instruction": self.instruction,
            "checkpoint": self.checkpoint,
            "notes": self.notes,
        }

    def panel(self) -> np.ndarray:
        """Fused map | pick heatmap | place heatmap (| similarity maps) as one (H', W', 3) uint8 picture."""
        from cliport.evaluation.visualize import action_panel

        return action_panel(self.obs, self.act, self.instruction, similarity=self.similarity)


class Predictor:
    """A trained run's agent acting on real (or any) RGB-D views fused exactly as the simulator fuses them.

    ``Predictor(run_dir, checkpoint="best", device="auto")`` (``run_dir`` a folder or ``hf://org/name[@rev]``)
    ``.predict(images, cameras, instruction)`` with
    ``images`` a list of (rgb (H, W, 3) uint8, depth (H, W) float32 metres) and ``cameras`` a list of
    :class:`CameraConfig` (or cameras.json objects), one per view.
    """

    def __init__(
        self,
        run_dir: str,
        checkpoint: str = "best",
        device: str = "auto",
        bounds: Sequence[float] | np.ndarray | None = None,
        weights: dict[str, str] | None = None,
    ) -> None:
        from cliport.agents import PickPlaceAgent
        from cliport.utils.device import resolve_device

        self.bounds = check_bounds(bounds)
        self.checkpoint_path, self.checkpoint_step = resolve_checkpoint(run_dir, str(checkpoint))
        self.agent = PickPlaceAgent.from_pretrained(
            self.checkpoint_path, device=resolve_device(device), weights=weights
        )

    def fuse(
        self,
        images: Sequence[tuple[np.ndarray, np.ndarray]],
        cameras: Sequence[CameraConfig | dict[str, Any]],
        names: Sequence[tuple[str, str]] | None = None,
    ) -> tuple[dict[str, np.ndarray], list[str]]:
        """:func:`fuse_views` within this predictor's bounds."""
        return fuse_views(images, cameras, self.bounds, names)

    def predict(
        self,
        images: Sequence[tuple[np.ndarray, np.ndarray]],
        cameras: Sequence[CameraConfig | dict[str, Any]],
        instruction: str,
        names: Sequence[tuple[str, str]] | None = None,
    ) -> Prediction:
        """Fuse the views and act: the pick and place poses in the base frame (see :class:`Prediction`)."""
        obs, notes = self.fuse(images, cameras, names)
        return self.predict_heightmap(obs["color"], obs["height"], instruction, notes)

    def predict_heightmap(
        self, color: np.ndarray, height: np.ndarray, instruction: str, notes: list[str] | None = None
    ) -> Prediction:
        """Act on an already fused top-down map: color (320, 160, 3) uint8, height (320, 160) float32 metres
        above the bounds' z0."""
        if not isinstance(instruction, str) or not instruction.strip():
            raise ConfigError("the instruction must be a non-empty string (--lang)")
        shape = hm.heightmap_shape(self.bounds)
        color, height = np.asarray(color), np.asarray(height)
        if color.shape != (*shape, 3) or color.dtype != np.uint8:
            raise SceneError(
                f"the colour map must be {shape[0]} x {shape[1]} x 3 uint8, got {color.dtype} {color.shape}"
            )
        if height.shape != shape or not np.issubdtype(height.dtype, np.floating):
            raise SceneError(
                f"the height map must be {shape[0]} x {shape[1]} float metres, got {height.dtype} {height.shape}"
            )
        notes = list(notes or [])
        if not self.agent.uses_language:
            notes.append(f"{self.agent.name} ignores language: the instruction cannot change what it does")
        obs = {"color": color, "height": np.nan_to_num(height.astype(np.float32), nan=0.0)}
        act = self.agent.act(obs, instruction)

        def pose(pix: tuple[int, int], quat: Sequence[float]) -> dict[str, Any]:
            xyz = hm.pix_to_xyz(pix, obs["height"], self.bounds, hm.PIXEL_SIZE)
            return {"xyz": [round(c, 6) for c in xyz], "quat": [round(float(c), 6) for c in quat], "pixel": list(pix)}

        return Prediction(
            pick=pose(act["pick_pix"], act["pose0"][1]),
            place={**pose(act["place_pix"], act["pose1"][1]), "rotation_bin": act["place_bin"]},
            instruction=instruction,
            checkpoint=self.checkpoint_path,
            obs=obs,
            act=act,
            notes=notes,
            similarity=self.agent.similarity_heatmaps(obs, instruction),
        )
