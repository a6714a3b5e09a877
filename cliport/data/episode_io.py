"""One compressed file per episode: what the agents consume, stored compactly and written atomically.

File ``<seed:06d>.npz`` (numpy's zip container, deflate-compressed) with, for T actions:
- ``color``  uint8   (T, 320, 160, 3)  fused top-down colour before each action
- ``height`` uint16  (T, 320, 160)     height in units of 0.1 mm (lossless to 0.1 mm, max 6.5 m)
- ``pose0``, ``pose1`` float64 (T, 7)  action poses: xyz + quaternion xyzw
- ``reward`` float32 (T,)              reward earned by each action
- ``lang_goal`` str  (T,)              instruction in force when each action was chosen
- ``meta`` str ()                      JSON: task, mode, seed, total_reward, library version, ...
- optionally ``camera_color`` uint8 (T, 3, H, W, 3) and ``camera_depth`` float32 (T, 3, H, W).
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.errors import UserError

HEIGHT_UNIT = 1e-4  # metres per stored height unit


class EpisodeFileError(UserError, ValueError):
    """A missing, truncated or otherwise unreadable episode file; the message names the path."""


@dataclass
class EpisodeData:
    color: np.ndarray
    height: np.ndarray  # float32 metres
    pose0: np.ndarray
    pose1: np.ndarray
    reward: np.ndarray
    lang_goal: list[str]
    meta: dict[str, Any]

    def __len__(self) -> int:
        return len(self.color)


def _pose_array(poses: list) -> np.ndarray:
    return np.array([[*pos, *quat] for pos, quat in poses], dtype=np.float64).reshape(-1, 7)


def save_episode(path: str, steps: list[dict[str, Any]], meta: dict[str, Any], raw_images: bool = False) -> int:
    """Write an episode atomically (temp file + rename); returns the file size in bytes.

    ``steps`` are rollout steps: dicts with ``obs`` (``color``, ``height``[, ``cameras``]),
    ``action`` (``pose0``, ``pose1``), ``reward`` and ``lang_goal``.
    """
    arrays: dict[str, np.ndarray] = {
        "color": np.stack([s["obs"]["color"] for s in steps]).astype(np.uint8),
        "height": np.stack([np.round(np.clip(s["obs"]["height"], 0, None) / HEIGHT_UNIT) for s in steps]).astype(
            np.uint16
        ),
        "pose0": _pose_array([s["action"]["pose0"] for s in steps]),
        "pose1": _pose_array([s["action"]["pose1"] for s in steps]),
        "reward": np.array([s["reward"] for s in steps], dtype=np.float32),
        "lang_goal": np.array([s["lang_goal"] or "" for s in steps]),
        "meta": np.array(json.dumps(meta)),
    }
    if raw_images:
        arrays["camera_color"] = np.stack([[c["color"] for c in s["obs"]["cameras"]] for s in steps])
        arrays["camera_depth"] = np.stack([[c["depth"] for c in s["obs"]["cameras"]] for s in steps])
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return os.path.getsize(path)


def read_meta(path: str) -> dict[str, Any]:
    """The ``meta`` record of an episode file alone (cheap: the images are not decompressed)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z["meta"]))
    except FileNotFoundError as e:
        raise EpisodeFileError(f"episode file not found: {path}") from e
    except (zipfile.BadZipFile, KeyError, ValueError, OSError, EOFError) as e:
        raise EpisodeFileError(f"corrupt episode file {path}: {e}") from e


def load_episode(path: str) -> EpisodeData:
    """Read an episode file; raises EpisodeFileError naming the path if it is missing or corrupt."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = EpisodeData(
                color=z["color"],
                height=z["height"].astype(np.float32) * HEIGHT_UNIT,
                pose0=z["pose0"],
                pose1=z["pose1"],
                reward=z["reward"],
                lang_goal=[str(s) for s in z["lang_goal"]],
                meta=json.loads(str(z["meta"])),
            )
    except FileNotFoundError as e:
        raise EpisodeFileError(f"episode file not found: {path}") from e
    except (zipfile.BadZipFile, KeyError, ValueError, OSError, EOFError) as e:
        raise EpisodeFileError(f"corrupt episode file {path}: {e}") from e
    if not (len(data.color) == len(data.height) == len(data.pose0) == len(data.pose1) == len(data.lang_goal)):
        raise EpisodeFileError(f"corrupt episode file {path}: arrays have different lengths")
    if len(data) == 0:
        raise EpisodeFileError(f"corrupt episode file {path}: no steps")
    return data
