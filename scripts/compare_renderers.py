"""Do EGL and TinyRenderer give the same observation of the same scene? Differences as JSON.

Usage: python scripts/compare_renderers.py [--tasks block-insertion packing-shapes] [--seed 0] [--camera-scale 1]
Renders the first observation of each task's seed with ``renderer="cpu"`` (TinyRenderer) and ``"egl"``
(PyBullet's EGL plugin: the GPU where there is one, Mesa's software OpenGL elsewhere) and reports how
many fused colour pixels and height cells differ and by how much. Imports no torch (EGL through Mesa
must not share a process with it, see docs/workcell.md).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from cliport import tasks
from cliport.env.environment import EnvConfig, Environment

DEFAULT_TASKS = ["block-insertion", "put-block-in-bowl-seen-colors", "packing-shapes"]


def compare(task: str, seed: int, camera_scale: float) -> dict[str, Any]:
    """The two renderers' observations of one scene, compared."""
    obs, names = {}, {}
    for renderer in ("cpu", "egl"):
        with Environment(
            EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer), task=tasks.make(task, "train")
        ) as env:
            obs[renderer], names[renderer] = env.reset(seed), env.renderer_name
    tiny, egl = obs["cpu"], obs["egl"]
    color = np.abs(tiny["color"].astype(np.int16) - egl["color"].astype(np.int16))
    height_mm = np.abs(tiny["height"] - egl["height"]) * 1000
    return {
        "renderers": [names["cpu"], names["egl"]],
        "color_pixels_differing": float((color.max(axis=-1) > 0).mean()),
        "color_pixels_differing_by_more_than_8": float((color.max(axis=-1) > 8).mean()),
        "color_mean_abs_difference": float(color.mean()),
        "height_cells_differing_by_more_than_1mm": float((height_mm > 1).mean()),
        "height_median_abs_difference_mm": float(np.median(height_mm)),
        "height_p99_abs_difference_mm": float(np.percentile(height_mm, 99)),
        "empty_height_cells": {"tiny": float((tiny["height"] == 0).mean()), "egl": float((egl["height"] == 0).mean())},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=DEFAULT_TASKS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--camera-scale", type=float, default=1.0)
    args = parser.parse_args()
    if args.camera_scale <= 0:
        parser.error("--camera-scale must be > 0")
    print(json.dumps({task: compare(task, args.seed, args.camera_scale) for task in args.tasks}, indent=2))


if __name__ == "__main__":
    main()
