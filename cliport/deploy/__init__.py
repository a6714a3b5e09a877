"""Bring your own scene: a trained run acting on your own RGB-D cameras, fused as the simulator fuses.

Sits above the agents, beside evaluation: :class:`Predictor` loads a run's checkpoint and predicts one
pick-and-place action from camera images (:mod:`cliport.deploy.scene` reads and checks them).
"""

from cliport.deploy.predictor import Prediction, Predictor, check_bounds, fuse_views, resolve_checkpoint
from cliport.deploy.scene import SceneError, fuse_scene, load_cameras, parse_camera, read_color, read_depth

__all__ = [
    "Prediction",
    "Predictor",
    "SceneError",
    "check_bounds",
    "fuse_scene",
    "fuse_views",
    "load_cameras",
    "parse_camera",
    "read_color",
    "read_depth",
    "resolve_checkpoint",
]
