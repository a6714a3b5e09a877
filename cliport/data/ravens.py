"""Datasets written by the reference CLIPort's and Ravens' ``demos.py``, imported as our episode files.

Layout of one split, ``{task}-{mode}/``: five folders ``action``, ``color``, ``depth``, ``info`` and
``reward``, each with one pickle per episode named ``{index:06d}-{seed}.pkl``. Each pickle is a list (an
array for the images) with one entry per step of the episode plus the final observation:

- ``color``: uint8 (T + 1, 3, 480, 640, 3), the three RealSense views; ``depth``: float32 (T + 1, 3, 480, 640)
- ``action``: T dicts with ``pose0`` and ``pose1`` ((x, y, z), (x, y, z, w)), then None
- ``reward``: the reward received before each entry (0 first; entry t + 1 is action t's reward)
- ``info``: dicts with ``lang_goal`` (and object poses keyed by body id)

Each step's three views are fused with the reference's camera configuration (ours at camera scale 1,
the same numbers) and fusion (:func:`cliport.env.heightmap.fuse_cameras`) into
``DATA_DIR/{task}-{mode}/{seed:06d}.npz``. Pickles are read with a restricted unpickler that allows numpy
arrays and scalars and Python's builtin containers only (:mod:`cliport.utils.safe_pickle`): a file that
names anything else is refused and nothing in it runs. Every file is read and checked before anything is
written; a re-run keeps the episodes already imported from the same folder.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.data.episode_io import dataset_dir, episode_path, kept_import, save_episode
from cliport.env import heightmap as hm
from cliport.env.cameras import realsense_d415
from cliport.errors import UserError
from cliport.utils.safe_pickle import NUMPY_GLOBALS, RestrictedUnpickler, UnreadablePickleError, UnsafePickleError

FIELDS = ("action", "color", "depth", "info", "reward")
_FILE = re.compile(r"(\d{6})-(\d+)\.pkl")
_SPLIT = re.compile(r"(?P<task>.+)-(?P<mode>train|val|test)")
IMAGE_SIZE = (480, 640)


class RavensImportError(UserError, ValueError):
    """A file of a Ravens-format dataset is missing, unreadable or inconsistent; the message names it."""


def is_ravens_dataset(folder: str) -> bool:
    """Whether ``folder`` is laid out as a Ravens-format split (its ``action`` and ``color`` folders)."""
    return all(os.path.isdir(os.path.join(folder, name)) for name in ("action", "color"))


def split_name(folder: str) -> tuple[str, str] | None:
    """(task, mode) from a split folder's name ``{task}-{mode}``, or None."""
    match = _SPLIT.fullmatch(os.path.basename(os.path.normpath(folder)))
    return (match["task"], match["mode"]) if match else None


def read_pickle(path: str) -> Any:
    """A pickle of the dataset, read with numpy arrays, numpy scalars and builtins only."""
    try:
        with open(path, "rb") as f:
            return RestrictedUnpickler(f, path, allowed=NUMPY_GLOBALS).load()
    except FileNotFoundError:
        raise RavensImportError(f"{path} is missing") from None
    except (UnsafePickleError, UnreadablePickleError):
        raise
    except Exception as err:  # noqa: BLE001 - whatever a truncated or foreign pickle makes pickle raise
        raise RavensImportError(f"{path} is truncated or not a pickle ({type(err).__name__}: {err})") from None


@dataclass
class RavensEpisode:
    """One checked episode: its index, seed and the five files."""

    index: int
    seed: int
    files: dict[str, str]
    n_actions: int


def find_episodes(folder: str) -> list[RavensEpisode]:
    """The episodes of a split folder, each with all five files present (sorted by index)."""
    names = sorted(f for f in os.listdir(os.path.join(folder, "action")) if _FILE.fullmatch(f))
    if not names:
        raise RavensImportError(f"{os.path.join(folder, 'action')} holds no {{index:06d}}-{{seed}}.pkl files")
    episodes = []
    for name in names:
        match = _FILE.fullmatch(name)
        assert match is not None
        files = {field: os.path.join(folder, field, name) for field in FIELDS}
        for path in files.values():
            if not os.path.isfile(path):
                raise RavensImportError(
                    f"{path} is missing (every episode has an action, color, depth, info and reward file)"
                )
        episodes.append(RavensEpisode(int(match[1]), int(match[2]), files, 0))
    return episodes


def _pose(value: Any, at: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    try:
        position, rotation = value
        position = tuple(float(x) for x in np.asarray(position, dtype=np.float64).reshape(3))
        rotation = tuple(float(x) for x in np.asarray(rotation, dtype=np.float64).reshape(4))
    except (TypeError, ValueError):
        raise RavensImportError(f"{at} must be ((x, y, z), (x, y, z, w)), got {value!r:.80}") from None
    if not all(math.isfinite(x) for x in (*position, *rotation)) or abs(np.linalg.norm(rotation) - 1) > 1e-2:
        raise RavensImportError(f"{at} must hold a finite position and a unit quaternion, got {value!r:.80}")
    return position, rotation


def load_episode(episode: RavensEpisode) -> dict[str, Any]:
    """Read and check one episode's five files: images, actions, rewards and instructions of each action."""
    data = {field: read_pickle(path) for field, path in episode.files.items()}
    color, depth = np.asarray(data["color"]), np.asarray(data["depth"])
    n = len(data["action"]) if isinstance(data["action"], list) else -1
    for field, value in data.items():
        if len(value) != n:
            raise RavensImportError(
                f"{episode.files[field]} has {len(value)} entries but {episode.files['action']} has {n}"
            )
    if color.dtype != np.uint8 or color.shape[1:] != (3, *IMAGE_SIZE, 3):
        raise RavensImportError(
            f"{episode.files['color']} must hold uint8 images (steps, 3, {IMAGE_SIZE[0]}, {IMAGE_SIZE[1]}, 3), got "
            f"{color.dtype} {color.shape}"
        )
    if not np.issubdtype(depth.dtype, np.floating) or depth.shape[1:] != (3, *IMAGE_SIZE):
        raise RavensImportError(
            f"{episode.files['depth']} must hold float depth images (steps, 3, {IMAGE_SIZE[0]}, {IMAGE_SIZE[1]}), got "
            f"{depth.dtype} {depth.shape}"
        )
    actions = data["action"][:-1]
    if n < 2 or data["action"][-1] is not None or any(not isinstance(a, dict) for a in actions):
        raise RavensImportError(
            f"{episode.files['action']} must list one dict per action and end with None (the final observation)"
        )
    steps = []
    for t, action in enumerate(actions):
        at = f"{episode.files['action']}: step {t}"
        info = data["info"][t]
        lang = info.get("lang_goal") if isinstance(info, dict) else None
        if not isinstance(lang, str):
            raise RavensImportError(f"{episode.files['info']}: step {t} has no lang_goal string")
        if "pose0" not in action or "pose1" not in action:
            raise RavensImportError(f"{at} has no pose0 / pose1")
        steps.append(
            {
                "pose0": _pose(action["pose0"], f"{at} pose0"),
                "pose1": _pose(action["pose1"], f"{at} pose1"),
                "reward": float(data["reward"][t + 1]),
                "lang_goal": lang,
            }
        )
    return {"color": color, "depth": depth.astype(np.float32, copy=False), "steps": steps}


def import_ravens(
    folder: str, data_dir: str, task: str | None = None, mode: str | None = None, log: Any = None
) -> dict[str, Any]:
    """Import the Ravens-format split ``folder`` as ``task``'s ``mode`` episodes under ``data_dir``
    (task and mode default to the folder's name ``{task}-{mode}``); returns a summary."""
    from cliport import __version__, tasks

    if not is_ravens_dataset(folder):
        raise RavensImportError(f"{folder} is not a Ravens-format dataset (no action/ and color/ folders)")
    named = split_name(folder)
    task = task or (named[0] if named else None)
    mode = mode or (named[1] if named else None)
    if task is None or mode is None:
        raise RavensImportError(
            f"cannot tell the task and mode of {folder} from its name ({{task}}-{{mode}}): pass --task and --mode"
        )
    if tasks.resolve(task) != [task]:
        raise RavensImportError(f"--task {task!r} is a multi-task group: import into one task")
    episodes = find_episodes(folder)
    source = os.path.abspath(folder)
    for episode in episodes:  # every file is read and checked before anything is written
        episode.n_actions = len(load_episode(episode)["steps"])
    out = dataset_dir(data_dir, task, mode)
    os.makedirs(out, exist_ok=True)
    cameras = realsense_d415()
    summary: dict[str, Any] = {
        "task": task, "mode": mode, "folder": out, "format": "ravens", "episodes": len(episodes),
        "imported": 0, "skipped": 0, "steps": 0, "seeds": [],
    }  # fmt: skip
    for episode in episodes:
        path = episode_path(out, episode.seed)
        summary["seeds"].append(episode.seed)
        if kept_import(path, source, RavensImportError):
            summary["skipped"] += 1
            continue
        loaded = load_episode(episode)
        steps = []
        for t, step in enumerate(loaded["steps"]):
            views = list(zip(loaded["color"][t], loaded["depth"][t], strict=True))
            fused = hm.fuse_cameras(views, cameras)
            steps.append(
                {
                    "obs": {"color": fused.color, "height": fused.height},
                    "action": {"pose0": step["pose0"], "pose1": step["pose1"]},
                    "reward": step["reward"],
                    "lang_goal": step["lang_goal"],
                }
            )
        meta = {
            "task": task,
            "mode": mode,
            "seed": episode.seed,
            "source": source,
            "source_file": os.path.basename(episode.files["action"]),
            "format": "ravens",
            "imported": True,
            "camera_scale": 1.0,
            "cliport_version": __version__,
            "total_reward": float(sum(s["reward"] for s in steps)),
            "n_steps": len(steps),
        }
        save_episode(path, steps, meta)
        summary["imported"] += 1
        summary["steps"] += len(steps)
        if log is not None:
            log(f"{episode.files['action']} -> {path} ({len(steps)} steps)")
    return summary
