"""Real demonstrations from your own cameras, converted into the project's episode files.

Source folder (``cliport-import --from DIR``): one sub-folder per demonstration, named
``episode-<index>`` (``episode-000``, ``episode-001``, ...); the index picks the seed of the episode
file, the index-th seed of the mode's protocol (:func:`cliport.data.seeds.episode_seeds`: train
0, 2, 4, ..., val 1, 3, ..., test 10001, 10003, ...). Other entries of DIR are ignored. Each holds:

- ``cameras.json``: the cameras, as for ``cliport-predict`` (:func:`cliport.deploy.scene.load_cameras`);
- ``steps.json``: a non-empty list with one object per pick-and-place action, in order::

      [{"rgb": ["c0.png", "c1.png"], "depth": ["d0.npy", "d1.png"],
        "pick": {"position": [x, y, z], "rotation": [x, y, z, w]},
        "place": {"position": [x, y, z], "rotation": [x, y, z, w]},
        "instruction": "put the red block in the brown box"}]

  ``rgb``/``depth``: the views before the action, one per camera in cameras.json order, paths
  relative to the episode folder (8-bit colour; depth ``.npy`` float metres or 16-bit PNG times the
  camera's ``depth_scale``); ``pick``/``place``: the gripper poses in the robot base frame (metres,
  quaternion xyzw).

Each step's views are fused by :func:`cliport.deploy.scene.fuse_scene` (the simulator's fusion) and
each episode is written by :func:`cliport.data.episode_io.save_episode` to
``DATA_DIR/<task>-<mode>/<seed:06d>.npz`` with reward 1/T per step (total 1) and meta ``imported``:
true, ``source`` (the episode folder), ``camera_scale`` None and the ``bounds``. With bounds other than
the simulator's, the poses are moved by the same offset as the box, into the simulator's frame the
agents are trained in (``cliport-predict --bounds`` moves predictions back).

Every step.json of DIR is checked before anything is written, and every step of an episode is read and
fused before its file is written (atomically), so a bad input leaves no file of its own; a problem is a
:class:`~cliport.errors.DemoImportError` naming the episode, step and field. Re-running resumes: valid episode files
already imported from the same folder are kept.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cliport.data.episode_io import dataset_dir, episode_path, kept_import, save_episode
from cliport.data.seeds import MODES, episode_seeds
from cliport.deploy.scene import SceneError, check_views, fuse_scene, load_cameras, read_color, read_depth
from cliport.env import heightmap as hm
from cliport.env.cameras import CameraConfig
from cliport.errors import DemoImportError
from cliport.utils.files import read_json

EPISODE_DIR = re.compile(r"episode-(\d+)")
STEP_FIELDS = ("rgb", "depth", "pick", "place", "instruction")
POSE_FIELDS = ("position", "rotation")


@dataclass
class SourceEpisode:
    """One checked ``episode-<index>`` folder: its cameras and its steps (paths made absolute)."""

    folder: str
    index: int
    cameras: list[CameraConfig]
    steps: list[dict[str, Any]] = field(default_factory=list)


def find_episodes(src: str) -> list[tuple[int, str]]:
    """(index, folder) of the ``episode-<index>`` folders of ``src``, sorted by index."""
    if not os.path.isdir(src):
        raise DemoImportError(f"--from {src} is not a folder")
    found: dict[int, str] = {}
    for name in sorted(os.listdir(src)):
        m = EPISODE_DIR.fullmatch(name)
        path = os.path.join(src, name)
        if not m or not os.path.isdir(path):
            continue
        index = int(m.group(1))
        if index in found:
            raise DemoImportError(
                f"{path} and {found[index]} have the same episode index {index}: rename one (episode-XXX)"
            )
        found[index] = path
    if not found:
        raise DemoImportError(f"{src} holds no episode-XXX folders (one per demonstration, e.g. episode-000)")
    return sorted(found.items())


def parse_pose(value: Any, at: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A ``{"position": [x, y, z], "rotation": [x, y, z, w]}`` pose as (position, unit quaternion)."""
    if not isinstance(value, dict):
        raise DemoImportError(f'{at} must be an object {{"position": [x, y, z], "rotation": [x, y, z, w]}}')
    unknown = sorted(set(value) - set(POSE_FIELDS))
    if unknown:
        raise DemoImportError(f"{at}: unknown field(s) {', '.join(unknown)} (fields: position, rotation)")
    out = []
    for key, n, what in (("position", 3, "[x, y, z] metres"), ("rotation", 4, "a quaternion [x, y, z, w]")):
        if key not in value:
            raise DemoImportError(f"{at}.{key} is missing: give {what}")
        v = value[key]
        ok = isinstance(v, list) and len(v) == n
        ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v)
        if not ok:
            raise DemoImportError(f"{at}.{key} must be {n} numbers, {what}, got {json.dumps(v)}")
        out.append(np.array(v, dtype=np.float64))
    norm = float(np.linalg.norm(out[1]))
    if abs(norm - 1.0) > 1e-2:
        raise DemoImportError(f"{at}.rotation must be a unit quaternion [x, y, z, w], got norm {norm:.4g}")
    return tuple(float(x) for x in out[0]), tuple(float(x) for x in out[1] / norm)


def _files(value: Any, key: str, at: str, folder: str, n_cameras: int) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(p, str) and p for p in value):
        raise DemoImportError(f"{at} {key} must be a list of file names, one per camera")
    if len(value) != n_cameras:
        raise DemoImportError(
            f"{at} {key} lists {len(value)} file(s) but cameras.json has {n_cameras} camera(s): give one per camera"
        )
    paths = [os.path.join(folder, p) for p in value]
    for p in paths:
        if not os.path.isfile(p):
            raise DemoImportError(f"{at} {key}: file not found: {p}")
    return paths


def check_episode(index: int, folder: str) -> SourceEpisode:
    """Read and check an episode folder's cameras.json and steps.json (not the images yet)."""
    try:
        cameras = load_cameras(os.path.join(folder, "cameras.json"))
    except SceneError as e:
        raise DemoImportError(f"{folder}: {e}") from None
    path = os.path.join(folder, "steps.json")
    absent = f"{folder}: steps.json not found (a list of steps: {', '.join(STEP_FIELDS)})"
    data = read_json(path, DemoImportError, absent)
    if not isinstance(data, list) or not data:
        raise DemoImportError(f"{path} must hold a non-empty list of steps, got {type(data).__name__}")
    episode = SourceEpisode(folder, index, cameras)
    for t, step in enumerate(data):
        at = f"{path}: step {t}"
        if not isinstance(step, dict):
            raise DemoImportError(f"{at} must be an object with {', '.join(STEP_FIELDS)}")
        unknown = sorted(set(step) - set(STEP_FIELDS))
        if unknown:
            raise DemoImportError(f"{at}: unknown field(s) {', '.join(unknown)} (fields: {', '.join(STEP_FIELDS)})")
        missing = [k for k in STEP_FIELDS if k not in step]
        if missing:
            raise DemoImportError(f"{at}: field {', '.join(missing)} is missing")
        instruction = step["instruction"]
        if not isinstance(instruction, str) or not instruction.strip():
            raise DemoImportError(f"{at}: field instruction must be a non-empty string")
        episode.steps.append(
            {
                "rgb": _files(step["rgb"], "rgb", f"{at}: field", folder, len(cameras)),
                "depth": _files(step["depth"], "depth", f"{at}: field", folder, len(cameras)),
                "pick": parse_pose(step["pick"], f"{at}: field pick"),
                "place": parse_pose(step["place"], f"{at}: field place"),
                "instruction": instruction.strip(),
            }
        )
    return episode


def _shift(pose: tuple, offset: np.ndarray) -> tuple:
    return tuple(float(x) for x in np.asarray(pose[0]) + offset), pose[1]


def convert_episode(episode: SourceEpisode, bounds: np.ndarray = hm.BOUNDS) -> tuple[list[dict[str, Any]], list[str]]:
    """Read and fuse every step of a checked episode: (steps for ``save_episode``, notes)."""
    offset = hm.BOUNDS[:, 0] - np.asarray(bounds)[:, 0]
    steps, notes = [], []
    reward = 1.0 / len(episode.steps)
    for t, step in enumerate(episode.steps):
        at = f"{os.path.join(episode.folder, 'steps.json')}: step {t}"
        try:
            key = "rgb"
            colors = [read_color(p) for p in step["rgb"]]
            key = "depth"
            depths = [
                read_depth(p, cam, i) for i, (p, cam) in enumerate(zip(step["depth"], episode.cameras, strict=True))
            ]
            key = "rgb/depth"
            images = list(zip(colors, depths, strict=True))
            check_views(images, episode.cameras, list(zip(step["rgb"], step["depth"], strict=True)))
            names = [f"camera {i} ({p})" for i, p in enumerate(step["rgb"])]
            fused, step_notes = fuse_scene(images, episode.cameras, bounds, names)
        except SceneError as e:
            raise DemoImportError(f"{at}: field {key}: {e}") from None
        notes += [f"{at}: {n}" for n in step_notes]
        steps.append(
            {
                "obs": {"color": fused.color, "height": fused.height},
                "action": {"pose0": _shift(step["pick"], offset), "pose1": _shift(step["place"], offset)},
                "reward": reward,
                "lang_goal": step["instruction"],
            }
        )
    return steps, notes


def import_demos(
    src: str,
    task: str,
    data_dir: str,
    mode: str = "train",
    bounds: np.ndarray = hm.BOUNDS,
    log: Any = None,
) -> dict[str, Any]:
    """Import every ``episode-XXX`` folder of ``src`` as ``task``'s ``mode`` demonstrations; returns the
    summary (episodes found, imported, skipped, steps imported, seeds, notes). ``task`` must be a
    registered single task (the dataset and training's validation resolve it through the registry)."""
    from cliport import __version__, tasks

    if mode not in MODES:
        raise DemoImportError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if tasks.resolve(task) != [task]:
        raise DemoImportError(f"--task {task!r} is a multi-task group: import into one task")
    bounds = np.asarray(bounds, dtype=np.float64).reshape(3, 2)
    found = find_episodes(src)
    seeds = episode_seeds(mode, max(i for i, _ in found) + 1)
    episodes = [check_episode(i, os.path.abspath(folder)) for i, folder in found]  # all steps.json first
    out = dataset_dir(data_dir, task, mode)
    os.makedirs(out, exist_ok=True)
    summary: dict[str, Any] = {
        "task": task,
        "mode": mode,
        "folder": out,
        "episodes": len(episodes),
        "imported": 0,
        "skipped": 0,
        "steps": 0,
        "seeds": [],
        "notes": [],
    }
    for episode in episodes:
        seed = seeds[episode.index]
        path = episode_path(out, seed)
        summary["seeds"].append(seed)
        if kept_import(path, episode.folder):
            summary["skipped"] += 1
            continue
        steps, notes = convert_episode(episode, bounds)
        meta = {
            "task": task,
            "mode": mode,
            "seed": seed,
            "source": episode.folder,
            "imported": True,
            "camera_scale": None,
            "bounds": bounds.tolist(),
            "cliport_version": __version__,
            "total_reward": 1.0,
            "n_steps": len(steps),
        }
        save_episode(path, steps, meta)
        summary["imported"] += 1
        summary["steps"] += len(steps)
        summary["notes"] += notes
        if log is not None:
            log(f"{episode.folder} -> {path} ({len(steps)} steps)")
    return summary
