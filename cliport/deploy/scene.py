"""A scene from your own cameras: cameras.json, colour and depth files, checked and fused top-down.

``cameras.json`` is a list with one object per camera holding the fields of
:class:`cliport.env.cameras.CameraConfig`::

    [{"image_size": [480, 640], "intrinsics": [450, 0, 320, 0, 450, 240, 0, 0, 1],
      "position": [1.0, 0.0, 0.75], "rotation": [x, y, z, w], "depth_scale": 0.001, "zrange": [0.01, 10]}]

``intrinsics`` may also be nested 3x3; ``rotation`` is the camera-to-world quaternion (camera z forward,
y down) in the robot base frame; ``depth_scale`` (metres per unit of integer depth images) and
``zrange`` (valid depth, metres) are optional. Every problem is a :class:`SceneError` naming the camera,
file and field.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import fields
from typing import Any

import cv2
import numpy as np

from cliport.env import heightmap as hm
from cliport.env.cameras import CameraConfig
from cliport.errors import UserError
from cliport.utils.files import read_json

#: A median depth above this (metres) is taken for a wrong unit (millimetres given as metres).
MAX_MEDIAN_DEPTH = 10.0
#: A median depth below this (metres) is taken for a wrong depth_scale.
MIN_MEDIAN_DEPTH = 0.05
_FIELDS = [f.name for f in fields(CameraConfig)]
_REQUIRED = ("image_size", "intrinsics", "position", "rotation")


class SceneError(UserError, ValueError):
    """Unusable camera images or camera models; the message names the camera, file and field."""


def _numbers(value: Any, n: int, where: str, what: str) -> tuple[float, ...]:
    arr = None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        pass
    if arr is None or arr.size != n or arr.ndim == 0 or not np.all(np.isfinite(arr)):
        raise SceneError(f"{where} must be {what}, got {json.dumps(value) if _jsonable(value) else value!r}")
    return tuple(float(x) for x in arr.ravel())


def _jsonable(value: Any) -> bool:
    try:
        json.dumps(value)
        return True
    except (TypeError, ValueError):
        return False


def parse_camera(data: Any, index: int, source: str = "cameras.json") -> CameraConfig:
    """One camera object of cameras.json (a dict) as a checked CameraConfig (rotation normalised)."""
    at = f"{source}: camera {index}"
    if not isinstance(data, dict):
        raise SceneError(f"{at} must be an object with {', '.join(_REQUIRED)}, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_FIELDS))
    if unknown:
        raise SceneError(f"{at}: unknown field(s) {', '.join(unknown)} (fields: {', '.join(_FIELDS)})")
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise SceneError(f"{at}: missing field(s) {', '.join(missing)}")
    size = _numbers(data["image_size"], 2, f"{at}: field image_size", "[rows, cols]")
    if any(s < 1 or s != int(s) for s in size):
        raise SceneError(f"{at}: field image_size must be two positive integers [rows, cols], got {size}")
    k = np.array(_numbers(data["intrinsics"], 9, f"{at}: field intrinsics", "3x3 numbers (9, row-major)"))
    k = k.reshape(3, 3)
    if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]):
        raise SceneError(
            f"{at}: field intrinsics must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {k.tolist()}"
        )
    position = _numbers(data["position"], 3, f"{at}: field position", "[x, y, z] metres")
    rotation = np.array(_numbers(data["rotation"], 4, f"{at}: field rotation", "a quaternion [x, y, z, w]"))
    norm = float(np.linalg.norm(rotation))
    if abs(norm - 1.0) > 1e-2:
        raise SceneError(f"{at}: field rotation must be a unit quaternion [x, y, z, w], got norm {norm:.4g}")
    out: dict[str, Any] = {}
    if data.get("zrange") is not None:
        near, far = _numbers(data["zrange"], 2, f"{at}: field zrange", "[near, far] metres")
        if not 0 <= near < far:
            raise SceneError(f"{at}: field zrange must be [near, far] with 0 <= near < far, got {[near, far]}")
        out["zrange"] = (near, far)
    if data.get("depth_scale") is not None:
        scale = data["depth_scale"]
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not math.isfinite(scale) or scale <= 0:
            raise SceneError(f"{at}: field depth_scale must be a positive number (metres per unit), got {scale!r}")
        out["depth_scale"] = float(scale)
    return CameraConfig(
        image_size=(int(size[0]), int(size[1])),
        intrinsics=tuple(float(c) for c in k.ravel()),
        position=position,  # type: ignore[arg-type]  # three floats: checked above
        rotation=tuple(float(c) for c in rotation / norm),  # type: ignore[arg-type]  # tuple() of an iterable has no length in its type
        **out,
    )


def load_cameras(path: str) -> list[CameraConfig]:
    """Read and check a cameras.json file (a list of camera objects)."""
    data = read_json(path, SceneError, f"cameras file not found: {path}")
    if not isinstance(data, list) or not data:
        raise SceneError(f"{path} must hold a non-empty list with one object per camera, got {type(data).__name__}")
    return [parse_camera(c, i, path) for i, c in enumerate(data)]


def read_color(path: str) -> np.ndarray:
    """An 8-bit colour image file as (H, W, 3) uint8 RGB (an alpha channel is dropped)."""
    if not os.path.isfile(path):
        raise SceneError(f"colour image not found: {path}")
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SceneError(f"{path} is not a readable image")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4):
        raise SceneError(f"{path} must be an 8-bit RGB image, got {image.dtype} with shape {image.shape}")
    return np.ascontiguousarray(image[..., 2::-1])


def read_depth(path: str, camera: CameraConfig, index: int) -> np.ndarray:
    """A depth file as (H, W) float32 metres: ``.npy`` float metres, or an integer ``.npy``/16-bit PNG
    times the camera's ``depth_scale``. The unit is checked (see :func:`check_depth`)."""
    if not os.path.isfile(path):
        raise SceneError(f"depth image not found: {path}")
    if path.lower().endswith(".npy"):
        try:
            raw = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as e:
            raise SceneError(f"{path} is not a readable .npy array: {e}") from None
    else:
        raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise SceneError(f"{path} is not a readable image (depth must be .npy float metres or a 16-bit PNG)")
    return depth_in_metres(raw, path, camera, index)


def depth_in_metres(raw: np.ndarray, name: str, camera: CameraConfig, index: int) -> np.ndarray:
    """A (H, W) depth array as float32 metres: floats are metres, integers are multiplied by the camera's
    ``depth_scale`` (required then). The unit is checked (see :func:`check_depth`)."""
    raw = np.asarray(raw)
    if raw.ndim != 2:
        raise SceneError(f"depth {name} (camera {index}) must be one channel (H, W), got shape {raw.shape}")
    if np.issubdtype(raw.dtype, np.integer):
        if raw.dtype == np.uint8:
            raise SceneError(f"depth {name} is 8-bit: save depth as 16-bit PNG (with depth_scale) or .npy metres")
        if camera.depth_scale is None:
            raise SceneError(
                f"depth {name} holds integers ({raw.dtype}) but camera {index} has no depth_scale: add "
                '"depth_scale" (metres per unit, e.g. 0.001 for millimetres) to that camera in cameras.json'
            )
        depth = raw.astype(np.float32) * np.float32(camera.depth_scale)
        check_depth(depth, name, index, camera.depth_scale, camera.zrange[1])
    elif np.issubdtype(raw.dtype, np.floating):
        depth = raw.astype(np.float32)
        check_depth(depth, name, index, far=camera.zrange[1])
    else:
        raise SceneError(f"depth {name} must hold numbers, got dtype {raw.dtype}")
    return depth


def check_depth(
    depth: np.ndarray, name: str, index: int, depth_scale: float | None = None, far: float | None = None
) -> None:
    """SceneError when a (H, W) depth in metres has no valid value or a median that no tabletop camera
    sees (a wrong unit: millimetres given as metres, or a wrong depth_scale). ``depth_scale``: the scale
    the depth was converted with from integers, None for float metres; ``far``: the camera's far plane,
    whose values (nothing there, as a simulator renders the sky) do not count."""
    valid = np.isfinite(depth) & (depth > 0)
    if far is not None:
        valid &= ~np.isclose(depth, far, rtol=1e-3, atol=0.0)
    valid = depth[valid]
    if valid.size == 0:
        raise SceneError(f"depth {name} (camera {index}) has no valid value (all zero, negative or not finite)")
    median = float(np.median(valid))
    if MIN_MEDIAN_DEPTH <= median <= MAX_MEDIAN_DEPTH:
        return
    if depth_scale is not None:
        hint = f"check depth_scale {depth_scale:g} of camera {index} in cameras.json (metres per unit)"
    else:
        hint = (
            "depth must be in metres: pass float metres in a .npy, or a 16-bit PNG with "
            '"depth_scale" in cameras.json (0.001 for millimetres)'
        )
    raise SceneError(
        f"depth {name} (camera {index}) has a median of {median:.4g} m, outside "
        f"[{MIN_MEDIAN_DEPTH:g}, {MAX_MEDIAN_DEPTH:g}] m: wrong unit? {hint}"
    )


def check_views(
    images: Sequence[tuple[np.ndarray, np.ndarray]],
    cameras: Sequence[CameraConfig],
    names: Sequence[tuple[str, str]] | None = None,
) -> None:
    """SceneError unless there is one (colour (H, W, 3) uint8, depth (H, W)) pair per camera, each of
    the camera's image_size. ``names`` are the (colour, depth) sources for the messages."""
    if len(images) != len(cameras):
        raise SceneError(f"{len(images)} image pair(s) for {len(cameras)} camera(s) in cameras.json: give one each")
    names = names or [(f"colour image {i}", f"depth image {i}") for i in range(len(images))]
    for i, ((color, depth), cam, (cname, dname)) in enumerate(zip(images, cameras, names, strict=True)):
        color, depth = np.asarray(color), np.asarray(depth)
        rows, cols = cam.image_size
        if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
            raise SceneError(f"{cname} (camera {i}) must be (H, W, 3) uint8, got {color.dtype} {color.shape}")
        for name, shape in ((cname, color.shape[:2]), (dname, depth.shape)):
            if tuple(shape) != (rows, cols):
                raise SceneError(
                    f"{name} (camera {i}) is {shape[0]} x {shape[1]} (rows x cols) but camera {i}'s image_size "
                    f"is [{rows}, {cols}]: give images of that size or fix image_size and intrinsics"
                )


def fuse_scene(
    images: Sequence[tuple[np.ndarray, np.ndarray]],
    cameras: Sequence[CameraConfig],
    bounds: np.ndarray = hm.BOUNDS,
    names: Sequence[str] | None = None,
) -> tuple[hm.FusedMap, list[str]]:
    """Fuse checked views with :func:`cliport.env.heightmap.fuse_cameras` (the simulator's fusion).

    Returns the fused map and notes (cameras that contributed no point). SceneError when the map is
    empty, naming the cameras. ``names`` label the cameras in messages.
    """
    views = [(np.asarray(c), np.asarray(d, dtype=np.float32)) for c, d in images]
    fused = hm.fuse_cameras(views, cameras, bounds, hm.PIXEL_SIZE)
    names = names or [f"camera {i}" for i in range(len(cameras))]
    blind = [n for n, cells in zip(names, fused.cells_per_camera, strict=True) if cells == 0]
    where = (
        f"the workspace x [{bounds[0, 0]:g}, {bounds[0, 1]:g}], y [{bounds[1, 0]:g}, {bounds[1, 1]:g}], "
        f"z [{bounds[2, 0]:g}, {bounds[2, 1]:g}] m"
    )
    if len(blind) == len(names):
        raise SceneError(
            f"the fused map is empty: no point of {', '.join(blind)} falls inside {where}; check the camera "
            "poses (camera-to-world in the robot base frame, z forward, y down), the depth unit and --bounds"
        )
    notes = [f"{n} contributed no point inside {where} (check its pose)" for n in blind]
    return fused, notes
