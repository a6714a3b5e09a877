"""One compressed file per episode: what the agents consume, stored compactly and written atomically.

Layout: ``DATA_DIR/<task>-<mode>/<seed:06d>.npz`` (:func:`dataset_dir`, :func:`episode_path`).
File ``<seed:06d>.npz`` (numpy's zip container, deflate-compressed) with, for T actions:
- ``color``  uint8   (T, 320, 160, 3)  fused top-down colour before each action
- ``height`` uint16  (T, 320, 160)     height in units of 0.1 mm (lossless to 0.1 mm, max 6.5 m)
- ``pose0``, ``pose1`` float64 (T, 7)  action poses: xyz + quaternion xyzw
- ``reward`` float32 (T,)              reward earned by each action
- ``lang_goal`` str  (T,)              instruction in force when each action was chosen
- ``meta`` str ()                      JSON: task, mode, seed, total_reward, library version, ...
- optionally ``camera_color`` uint8 (T, 3, H, W, 3) and ``camera_depth`` float32 (T, 3, H, W);
- optionally, for K other instructions of each step's scene (``cliport-demos --every-instruction``):
  ``variant_lang`` str (T, K) and ``variant_pose0``, ``variant_pose1`` float64 (T, K, 7), the oracle's action
  for each from the same observation.
"""

from __future__ import annotations

import json
import os
import re
import zipfile
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.errors import DemoImportError, UserError

_EPISODE_FILE = re.compile(r"(\d{6})\.npz")
HEIGHT_UNIT = 1e-4  # metres per stored height unit
REQUIRED_ARRAYS = ("color", "height", "pose0", "pose1", "reward", "lang_goal", "meta")
NOT_A_DEMO = "truncated or not a demo file"
# What reading a damaged zip member can raise: bad CRC, bad deflate stream, bad .npy header, short read.
_MEMBER_ERRORS = (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError)


class EpisodeFileError(UserError, ValueError):
    """A missing, truncated or otherwise unreadable episode file; the message names the path."""


def dataset_dir(data_dir: str, task: str, mode: str) -> str:
    """The folder of a task's episodes of one split."""
    return os.path.join(data_dir, f"{task}-{mode}")


def episode_path(folder: str, seed: int) -> str:
    """The episode file of ``seed`` in a dataset folder."""
    return os.path.join(folder, f"{seed:06d}.npz")


def existing_seeds(folder: str) -> list[int]:
    """Seeds of the finished episode files in a dataset folder, sorted."""
    return sorted(int(m.group(1)) for f in os.listdir(folder) if (m := _EPISODE_FILE.fullmatch(f)))


@dataclass
class EpisodeData:
    color: np.ndarray
    height: np.ndarray  # float32 metres
    pose0: np.ndarray
    pose1: np.ndarray
    reward: np.ndarray
    lang_goal: list[str]
    meta: dict[str, Any]
    variant_lang: list[list[str]] | None = None  # (T, K) other instructions of each step's scene
    variant_pose0: np.ndarray | None = None  # (T, K, 7) the oracle's pick pose for each
    variant_pose1: np.ndarray | None = None  # (T, K, 7) and its place pose

    def __len__(self) -> int:
        return len(self.color)

    def instruction(self, t: int, k: int) -> tuple[str, np.ndarray, np.ndarray]:
        """Step ``t``'s instruction ``k`` with its pick and place poses (7,): 0 the recorded one, 1..K the
        variants."""
        if k == 0:
            return self.lang_goal[t], self.pose0[t], self.pose1[t]
        if self.variant_lang is None or self.variant_pose0 is None or self.variant_pose1 is None:
            raise IndexError(f"instruction {k} of an episode that records no variants")
        return self.variant_lang[t][k - 1], self.variant_pose0[t, k - 1], self.variant_pose1[t, k - 1]


def _pose_array(poses: list) -> np.ndarray:
    return np.array([[*pos, *quat] for pos, quat in poses], dtype=np.float64).reshape(-1, 7)


def save_episode(path: str, steps: list[dict[str, Any]], meta: dict[str, Any], raw_images: bool = False) -> int:
    """Write an episode atomically (temp file + rename); returns the file size in bytes.

    ``steps`` are rollout steps: dicts with ``obs`` (``color``, ``height``[, ``cameras``]),
    ``action`` (``pose0``, ``pose1``), ``reward`` and ``lang_goal``.
    """
    arrays: dict[str, Any] = {
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
    if any("variants" in s for s in steps):
        variants = [s.get("variants", []) for s in steps]
        counts = sorted({len(v) for v in variants})
        if len(counts) != 1:
            raise ValueError(f"every step must record the same number of instruction variants, got {counts}")
        shape = (len(steps), counts[0])
        arrays["variant_lang"] = np.array([[lang for lang, _ in v] for v in variants], dtype=str).reshape(shape)
        for key in ("pose0", "pose1"):
            poses = [_pose_array([action[key] for _, action in v]) for v in variants]
            arrays[f"variant_{key}"] = np.stack(poses).reshape(*shape, 7)
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


def _open(path: str) -> np.lib.npyio.NpzFile:
    """The episode's npz archive, with its members checked against :data:`REQUIRED_ARRAYS`."""
    if not os.path.exists(path):
        raise EpisodeFileError(f"episode file not found: {path}")
    # numpy takes anything that is not a zip for a pickle and answers with advice to load it unsafely;
    # a zip's central directory sits at its end, so a truncated episode fails this test too.
    try:
        is_zip = zipfile.is_zipfile(path)
    except OSError as e:
        raise EpisodeFileError(f"cannot read episode file {path}: {e.strerror or e}") from None
    if not is_zip:
        raise EpisodeFileError(f"corrupt episode file {path}: {NOT_A_DEMO}")
    try:
        z = np.load(path, allow_pickle=False)
    except (*_MEMBER_ERRORS, KeyError):
        raise EpisodeFileError(f"corrupt episode file {path}: {NOT_A_DEMO}") from None
    missing = [k for k in REQUIRED_ARRAYS if k not in z.files]
    if missing:
        z.close()
        raise EpisodeFileError(f"corrupt episode file {path}: {NOT_A_DEMO} (no {', '.join(missing)} array)")
    return z


def _read(z: np.lib.npyio.NpzFile, key: str, path: str) -> np.ndarray:
    try:
        return z[key]
    except _MEMBER_ERRORS:
        raise EpisodeFileError(f"corrupt episode file {path}: the {key!r} array is damaged") from None


def _meta(z: np.lib.npyio.NpzFile, path: str) -> dict[str, Any]:
    try:
        meta = json.loads(str(_read(z, "meta", path)))
    except json.JSONDecodeError:
        meta = None
    if not isinstance(meta, dict):
        raise EpisodeFileError(f"corrupt episode file {path}: the 'meta' array is not a JSON object")
    return meta


def check_episode_file(path: str) -> int:
    """Cheaply check an episode file and return its number of steps; EpisodeFileError if it is bad.

    Reads the zip's central directory and the small ``reward`` and ``meta`` arrays, which catches a
    missing, empty, truncated or foreign file. It does not decompress the large ``color``/``height``
    arrays, so damage inside them (a flipped byte in the middle of an intact-length file) is only
    found by :func:`load_episode`.
    """
    with _open(path) as z:
        return _checked_steps(z, path)


def _checked_steps(z: np.lib.npyio.NpzFile, path: str) -> int:
    """The cheap checks of :func:`check_episode_file` on an open archive; its number of steps."""
    n_steps = len(_read(z, "reward", path))
    _meta(z, path)
    if n_steps == 0:
        raise EpisodeFileError(f"corrupt episode file {path}: no steps")
    return n_steps


def read_instructions(path: str) -> list[list[str]]:
    """Per step, the recorded instruction followed by the variants the file records (none for most files),
    after the checks of :func:`check_episode_file`; cheap: the images are not decompressed."""
    with _open(path) as z:
        _checked_steps(z, path)
        recorded = [str(s) for s in _read(z, "lang_goal", path)]
        if "variant_lang" not in z.files:
            return [[lang] for lang in recorded]
        variants = _read(z, "variant_lang", path)
    if len(variants) != len(recorded):
        raise EpisodeFileError(f"corrupt episode file {path}: variant arrays have different lengths")
    return [[lang, *(str(s) for s in row)] for lang, row in zip(recorded, variants, strict=True)]


def read_poses(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the pick and place poses of the recorded instruction followed by those of the variants the file
    records: two (T, 1 + K, 7) arrays; cheap: the images are not decompressed."""
    with _open(path) as z:
        poses = [_read(z, key, path)[:, None] for key in ("pose0", "pose1")]
        if "variant_pose0" in z.files:
            variants = [_read(z, f"variant_{key}", path) for key in ("pose0", "pose1")]
            if any(len(v) != len(poses[0]) for v in variants):
                raise EpisodeFileError(f"corrupt episode file {path}: variant arrays have different lengths")
            poses = [np.concatenate([p, v], axis=1) for p, v in zip(poses, variants, strict=True)]
    return poses[0], poses[1]


def read_meta(path: str) -> dict[str, Any]:
    """The ``meta`` record of an episode file alone (cheap: the images are not decompressed)."""
    with _open(path) as z:
        return _meta(z, path)


def load_episode(path: str) -> EpisodeData:
    """Read an episode file; raises EpisodeFileError naming the path if it is missing or corrupt."""
    with _open(path) as z:
        data = EpisodeData(
            color=_read(z, "color", path),
            height=_read(z, "height", path).astype(np.float32) * HEIGHT_UNIT,
            pose0=_read(z, "pose0", path),
            pose1=_read(z, "pose1", path),
            reward=_read(z, "reward", path),
            lang_goal=[str(s) for s in _read(z, "lang_goal", path)],
            meta=_meta(z, path),
        )
        if "variant_lang" in z.files:
            data.variant_lang = [[str(s) for s in row] for row in _read(z, "variant_lang", path)]
            data.variant_pose0 = _read(z, "variant_pose0", path)
            data.variant_pose1 = _read(z, "variant_pose1", path)
            if not (len(data.variant_lang) == len(data.variant_pose0) == len(data.variant_pose1) == len(data.reward)):
                raise EpisodeFileError(f"corrupt episode file {path}: variant arrays have different lengths")
    if not (len(data.color) == len(data.height) == len(data.pose0) == len(data.pose1) == len(data.lang_goal)):
        raise EpisodeFileError(f"corrupt episode file {path}: arrays have different lengths")
    if len(data) == 0:
        raise EpisodeFileError(f"corrupt episode file {path}: no steps")
    return data


def kept_import(path: str, source: str) -> bool:
    """True when ``path`` is a valid episode file imported from ``source`` (a resumed import keeps it); False
    when it is missing or damaged; DemoImportError when it holds another episode."""
    if not os.path.exists(path):
        return False
    try:
        check_episode_file(path)
        meta = read_meta(path)
    except EpisodeFileError:
        return False  # truncated or damaged: import it again
    if not meta.get("imported") or meta.get("source") != source:
        raise DemoImportError(
            f"{path} already holds an episode that is not an import of {source} "
            f"(source {meta.get('source', 'simulated')!r}): use another --data-dir or remove it"
        )
    return True
