"""Datasets of the reference CLIPort and of Ravens (the layout their ``demos.py`` writes) imported as
the project's episode files (``cliport-import --format ravens``, or detected).

Source folder ``DIR`` (``{task}-{mode}``, e.g. ``put-block-in-bowl-seen-colors-train``) holds five
folders ``action``, ``color``, ``depth``, ``info`` and ``reward``, each with one pickle per episode named
``{index:06d}-{seed}.pkl``. Each pickle holds one entry per observation of the episode, T actions giving
T + 1 observations (the last one after the last action):

- ``color``: (T + 1, 3, H, W, 3) uint8, the three cameras of the reference's ``RealSenseD415.CONFIG``
  (front, left, right; 480 x 640, or a uniformly scaled size with scaled intrinsics);
- ``depth``: (T + 1, 3, H, W) float, metres along the optical axis;
- ``action``: T dicts with ``pose0`` (pick) and ``pose1`` (place), each (xyz, quaternion xyzw) in the
  simulator's frame, then None;
- ``reward``: T + 1 numbers: 0 at the start, then the reward each action earned;
- ``info``: T + 1 dicts; ``info[t]["lang_goal"]`` is the instruction in force when action t was chosen
  (missing: "task completed.", as the reference's dataset does).

Each step's three images are fused by :func:`cliport.env.heightmap.fuse_cameras` with those cameras
(the reference's rule, see docs/workcell.md), and each episode is written by
:func:`cliport.data.episode_io.save_episode` to ``DATA_DIR/<task>-<mode>/<seed:06d>.npz`` with the
episode's own seed (the reference's seed protocol is ours), meta ``imported``: true, ``format``:
``ravens``, ``source`` (the episode's action pickle) and ``camera_scale`` (H / 480).

Pickles are read by :func:`safe_unpickler` (:mod:`cliport.utils.safe_pickle`), which builds numpy
arrays, numpy scalars and dtypes and built-in containers only: a pickle that names anything else (a
function such as ``os.system``, any class) is refused before any of it runs. Every episode's five
files are read and checked before the first file is written; re-running resumes (episode files already
imported from the same pickles are kept). Every problem is one
:class:`~cliport.errors.DemoImportError` naming the file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.data.episode_io import dataset_dir, episode_path, kept_import, save_episode
from cliport.data.seeds import MODES, seed_mode
from cliport.env import heightmap as hm
from cliport.env.cameras import CameraConfig, realsense_d415
from cliport.errors import DemoImportError
from cliport.utils.safe_pickle import NUMPY_GLOBALS, RestrictedUnpickler, UnsafePickleError

FIELDS = ("action", "color", "depth", "info", "reward")
EPISODE_FILE = re.compile(r"(\d{6})-(\d+)\.pkl")
#: The reference dataset's instruction for steps whose info has no ``lang_goal``.
DEFAULT_LANG_GOAL = "task completed."
#: The reference's camera image size (rows, cols); other sizes must be a uniform scale of it.
REFERENCE_IMAGE_SIZE = (480, 640)
N_CAMERAS = 3


# ----------------------------------------------------------------------------- safe pickles
def safe_unpickler(file: Any, source: str = "pickle") -> RestrictedUnpickler:
    """An unpickler that builds numpy arrays, numpy scalars and dtypes and built-in containers only: any
    other name a pickle gives (``os.system``, ``builtins.eval``, any class) is refused before it is called."""
    return RestrictedUnpickler(file, source, allowed=NUMPY_GLOBALS)


def load_pickle(path: str) -> Any:
    """Unpickle ``path`` with :func:`safe_unpickler`; DemoImportError naming the file if it is unreadable,
    truncated, not a pickle, or names anything but numpy arrays, numpy scalars and built-in containers."""
    try:
        with open(path, "rb") as f:
            return safe_unpickler(f, path).load()
    except UnsafePickleError as e:
        raise DemoImportError(
            f"{path}: refused to load: the pickle names {e.global_name or e}; only numpy arrays, numpy scalars "
            "and built-in containers are allowed (nothing of the file was run)"
        ) from None
    except OSError as e:
        raise DemoImportError(f"cannot read {path}: {e.strerror or e}") from None
    except Exception as e:  # noqa: BLE001 - whatever a damaged pickle raises, it is the file's fault
        detail = " ".join(str(e).split())[:200]
        raise DemoImportError(
            f"{path}: truncated or not a pickle of the demos.py layout ({type(e).__name__}{': ' if detail else ''}"
            f"{detail})"
        ) from None


# ----------------------------------------------------------------------------- the layout
def is_ravens_folder(src: str) -> bool:
    """Whether ``src`` looks like a dataset of the demos.py layout (it has an ``action`` folder)."""
    return os.path.isdir(os.path.join(src, "action"))


@dataclass(frozen=True)
class RavensEpisode:
    """One episode of a Ravens-layout folder: its index, seed and five pickle paths."""

    index: int
    seed: int
    paths: dict[str, str]


def find_ravens_episodes(src: str, mode: str) -> list[RavensEpisode]:
    """The episodes of a Ravens-layout folder, sorted by index; every file name, sibling and seed checked."""
    missing = [f for f in FIELDS if not os.path.isdir(os.path.join(src, f))]
    if missing:
        raise DemoImportError(
            f"{src} has no {', '.join(f + '/' for f in missing)} folder: a dataset of the demos.py layout holds "
            "action/, color/, depth/, info/ and reward/ with one {index:06d}-{seed}.pkl per episode each"
        )
    names: dict[str, set[str]] = {}
    for field in FIELDS:
        folder = os.path.join(src, field)
        names[field] = set()
        for name in sorted(os.listdir(folder)):
            if not name.endswith(".pkl"):
                continue
            if not EPISODE_FILE.fullmatch(name):
                raise DemoImportError(
                    f"{os.path.join(folder, name)}: not an episode file name ({{index:06d}}-{{seed}}.pkl)"
                )
            names[field].add(name)
    for field in FIELDS:
        for name in sorted(names[field] ^ names["action"]):
            have, lack = (field, "action") if name in names[field] else ("action", field)
            raise DemoImportError(
                f"{os.path.join(src, lack, name)} is missing (its episode has {os.path.join(have, name)}; every "
                "episode needs action, color, depth, info and reward files)"
            )
    if not names["action"]:
        raise DemoImportError(f"{src}/action holds no episode files ({{index:06d}}-{{seed}}.pkl)")
    episodes: list[RavensEpisode] = []
    by_seed: dict[int, str] = {}
    by_index: dict[int, str] = {}
    for name in sorted(names["action"]):
        m = EPISODE_FILE.fullmatch(name)
        assert m is not None
        index, seed = int(m.group(1)), int(m.group(2))
        action = os.path.join(src, "action", name)
        for seen, key, what in ((by_seed, seed, "seed"), (by_index, index, "index")):
            if key in seen:
                raise DemoImportError(f"{action} and {seen[key]} have the same {what} {key}")
            seen[key] = action
        if seed_mode(seed) != mode:
            raise DemoImportError(
                f"{action}: seed {seed} is not a {mode} seed (train: even; val: odd below 10001; test: odd from "
                f"10001): import this folder with --mode {seed_mode(seed)}"
            )
        episodes.append(RavensEpisode(index, seed, {f: os.path.join(src, f, name) for f in FIELDS}))
    return sorted(episodes, key=lambda e: e.index)


def cameras_for(shape: tuple[int, int], path: str) -> list[CameraConfig]:
    """The reference's three cameras at an image size of (rows, cols): 480 x 640 or a uniform scale of it."""
    rows, cols = shape
    scale = rows / REFERENCE_IMAGE_SIZE[0]
    cameras = [c.scaled(scale) for c in realsense_d415()] if rows > 0 else []
    if (
        not cameras
        or rows * REFERENCE_IMAGE_SIZE[1] != cols * REFERENCE_IMAGE_SIZE[0]
        or cameras[0].image_size != shape
    ):
        raise DemoImportError(
            f"{path}: images of {rows} x {cols} (rows x cols) are not the reference cameras' 480 x 640 or a "
            "uniform scale of it (RealSenseD415.CONFIG)"
        )
    return cameras


def _pose(value: Any, at: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """An action pose (xyz, quaternion xyzw) as floats; DemoImportError naming ``at`` otherwise."""
    try:
        position, rotation = value
        position = np.asarray(position, dtype=np.float64)
        rotation = np.asarray(rotation, dtype=np.float64)
    except (TypeError, ValueError):
        raise DemoImportError(f"{at} must be a pair (xyz, quaternion xyzw), got {type(value).__name__}") from None
    if position.shape != (3,) or rotation.shape != (4,):
        raise DemoImportError(
            f"{at} must be (xyz, quaternion xyzw) of 3 and 4 numbers, got shapes {position.shape} and {rotation.shape}"
        )
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(rotation))):
        raise DemoImportError(f"{at} holds NaN or infinity")
    norm = float(np.linalg.norm(rotation))
    if abs(norm - 1.0) > 1e-2:
        raise DemoImportError(f"{at} quaternion must have unit length, got norm {norm:.4g}")
    return tuple(float(x) for x in position), tuple(float(x) for x in rotation)


@dataclass
class RavensData:
    """A checked episode: its T steps' camera images, poses, rewards and instructions."""

    color: np.ndarray  # (T + 1, 3, H, W, 3) uint8
    depth: np.ndarray  # (T + 1, 3, H, W) float
    poses: list[tuple[Any, Any]]  # T (pose0, pose1)
    rewards: list[float]  # T: the reward of each action
    lang_goals: list[str]  # T
    cameras: list[CameraConfig]
    defaulted_lang_goals: int


def read_episode(episode: RavensEpisode) -> RavensData:
    """Load an episode's five pickles safely and check their structure, step counts and image shapes."""
    paths = episode.paths
    actions = load_pickle(paths["action"])
    if not isinstance(actions, list | tuple) or len(actions) < 2:
        raise DemoImportError(
            f"{paths['action']}: must be a list of one action per step and None after the last, got "
            f"{type(actions).__name__}{f' of {len(actions)}' if isinstance(actions, list | tuple) else ''}"
        )
    n = len(actions)
    if actions[-1] is not None:
        raise DemoImportError(f"{paths['action']}: the last entry must be None (the observation after the last action)")
    poses = []
    for t, action in enumerate(actions[:-1]):
        at = f"{paths['action']}: step {t}"
        if not isinstance(action, dict) or "pose0" not in action or "pose1" not in action:
            raise DemoImportError(f"{at}: must be a dict with pose0 and pose1, got {type(action).__name__}")
        poses.append((_pose(action["pose0"], f"{at}: pose0"), _pose(action["pose1"], f"{at}: pose1")))

    def entries(field: str) -> list[Any] | np.ndarray:
        value = load_pickle(paths[field])
        if not isinstance(value, list | tuple | np.ndarray) or len(value) != n:
            got = f"{len(value)} entries" if isinstance(value, list | tuple | np.ndarray) else type(value).__name__
            raise DemoImportError(
                f"{paths[field]}: {got} but {paths['action']} has {n} (one per observation: {n - 1} actions and the "
                "final None)"
            )
        return list(value) if not isinstance(value, np.ndarray) else value

    rewards = []
    for t, r in enumerate(entries("reward")):
        if isinstance(r, bool) or not isinstance(r, int | float | np.integer | np.floating) or not math.isfinite(r):
            raise DemoImportError(f"{paths['reward']}: entry {t} must be a finite number, got {r!r}"[:300])
        rewards.append(float(r))
    lang_goals, defaulted = [], 0
    infos = entries("info")
    for t, info in enumerate(infos[:-1]):
        if info is not None and not isinstance(info, dict):
            raise DemoImportError(f"{paths['info']}: entry {t} must be a dict, got {type(info).__name__}")
        goal = (info or {}).get("lang_goal")
        if goal is None:
            defaulted += 1
            goal = DEFAULT_LANG_GOAL
        elif not isinstance(goal, str):
            raise DemoImportError(f"{paths['info']}: entry {t}: lang_goal must be a string, got {type(goal).__name__}")
        lang_goals.append(goal)

    color = load_pickle(paths["color"])
    if (
        not isinstance(color, np.ndarray)
        or color.dtype != np.uint8
        or color.ndim != 5
        or color.shape[1:2] != (N_CAMERAS,)
        or color.shape[-1] != 3
    ):
        got = f"{color.dtype} {color.shape}" if isinstance(color, np.ndarray) else type(color).__name__
        raise DemoImportError(f"{paths['color']}: must be a uint8 array (steps, 3 cameras, H, W, 3), got {got}")
    depth = load_pickle(paths["depth"])
    if not isinstance(depth, np.ndarray) or depth.dtype.kind != "f" or depth.shape != color.shape[:4]:
        got = f"{depth.dtype} {depth.shape}" if isinstance(depth, np.ndarray) else type(depth).__name__
        raise DemoImportError(
            f"{paths['depth']}: must be a float array (steps, 3 cameras, H, W) = {color.shape[:4]} as the colour "
            f"images, got {got}"
        )
    if len(color) != n:
        raise DemoImportError(
            f"{paths['color']}: {len(color)} observations but {paths['action']} has {n} entries (one per observation)"
        )
    cameras = cameras_for(color.shape[2:4], paths["color"])
    return RavensData(color, depth, poses, rewards[1:], lang_goals, cameras, defaulted)


def convert_episode(episode: RavensEpisode, data: RavensData) -> list[dict[str, Any]]:
    """Fuse each step's three camera images into the steps :func:`save_episode` writes."""
    steps = []
    for t, ((pose0, pose1), reward, goal) in enumerate(zip(data.poses, data.rewards, data.lang_goals, strict=True)):
        views = [(data.color[t, i], data.depth[t, i]) for i in range(N_CAMERAS)]
        fused = hm.fuse_cameras(views, data.cameras)
        if not any(fused.cells_per_camera):
            raise DemoImportError(
                f"{episode.paths['depth']}: step {t}: no point of the three cameras falls inside the workspace "
                "(are these RealSenseD415.CONFIG images with depth in metres?)"
            )
        steps.append(
            {
                "obs": {"color": fused.color, "height": fused.height},
                "action": {"pose0": pose0, "pose1": pose1},
                "reward": reward,
                "lang_goal": goal,
            }
        )
    return steps


def import_ravens(
    src: str, task: str, data_dir: str, mode: str = "train", log: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Import a Ravens-layout folder as ``task``'s ``mode`` episodes; returns the summary (episodes found,
    imported, skipped, steps, seeds, notes). Every episode to import is read and checked first."""
    from cliport import __version__, tasks

    if mode not in MODES:
        raise DemoImportError(f"--mode must be one of {', '.join(MODES)}, got {mode!r}")
    if tasks.resolve(task) != [task]:
        raise DemoImportError(f"--task {task!r} is a multi-task group: import into one task")
    src = os.path.abspath(src)
    if not os.path.isdir(src):
        raise DemoImportError(f"--from {src} is not a folder")
    notes = []
    m = re.fullmatch(r"(.+)-(train|val|test)", os.path.basename(src))
    if m and m.group(1) != task:
        notes.append(f"{src} is named for task {m.group(1)}; importing it as {task}")
    episodes = find_ravens_episodes(src, mode)
    out = dataset_dir(data_dir, task, mode)
    todo = [
        e for e in episodes if not (os.path.isdir(out) and kept_import(episode_path(out, e.seed), e.paths["action"]))
    ]
    defaulted = 0
    for episode in todo:  # every file of every episode to import, before anything is written
        defaulted += read_episode(episode).defaulted_lang_goals
    if defaulted:
        notes.append(
            f"{defaulted} step(s) had no lang_goal in their info: {DEFAULT_LANG_GOAL!r} used, as the reference does"
        )
    os.makedirs(out, exist_ok=True)
    summary: dict[str, Any] = {
        "task": task,
        "mode": mode,
        "format": "ravens",
        "folder": out,
        "episodes": len(episodes),
        "imported": 0,
        "skipped": len(episodes) - len(todo),
        "steps": 0,
        "seeds": [e.seed for e in episodes],
        "notes": notes,
    }
    for episode in todo:
        data = read_episode(episode)
        steps = convert_episode(episode, data)
        path = episode_path(out, episode.seed)
        meta = {
            "task": task,
            "mode": mode,
            "seed": episode.seed,
            "source": episode.paths["action"],
            "imported": True,
            "format": "ravens",
            "camera_scale": data.cameras[0].image_size[0] / REFERENCE_IMAGE_SIZE[0],
            "bounds": hm.BOUNDS.tolist(),
            "cliport_version": __version__,
            "total_reward": float(sum(data.rewards)),
            "n_steps": len(steps),
        }
        save_episode(path, steps, meta)
        summary["imported"] += 1
        summary["steps"] += len(steps)
        if log is not None:
            log(f"{episode.paths['action']} -> {path} ({len(steps)} steps)")
    return summary
