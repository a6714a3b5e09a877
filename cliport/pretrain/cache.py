"""The rendered crops on disk: rendered once, in shards of scenes, each written atomically; a re-run renders only
what is missing.

Layout of a cache folder::

    manifest.json              what the crops were rendered with (crop size, camera scale, renderer, format)
    train/seeds-000000-000024.npz   the crops of train scenes 0-24: ``images`` (N, S, S, 3) uint8 and ``meta``
    probe/seeds-1000000-1000024.npz (the crops' metadata as UTF-8 JSON), and the scenes' maps: ``map_color``
                               (25, H, W, 3) uint8, ``map_labels`` (25, H, W) uint8 and ``map_things`` (JSON);
                               probe scenes are held out of training

Train scenes are seeds 0, 1, 2, ...; probe scenes :data:`PROBE_FIRST_SEED` on, so no probe scene is ever trained
on. A folder rendered with other settings is refused in one line (its crops would silently differ); more scenes
than a folder holds are rendered and added.
"""

from __future__ import annotations

import concurrent.futures as cf
import io
import json
import multiprocessing as mp
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from cliport.errors import ConfigError
from cliport.utils.files import read_json, write_bytes, write_json

#: Bumped when the crops a seed renders change.
CACHE_FORMAT = 2
SPLITS = ("train", "probe")
#: The first seed of each split's scenes.
FIRST_SEED = {"train": 0, "probe": 1_000_000}
PROBE_FIRST_SEED = FIRST_SEED["probe"]
#: Scenes per shard file.
SCENES_PER_SHARD = 25


@dataclass
class CropSet:
    """Crops of one split: ``images`` (N, S, S, 3) uint8 and ``meta`` (N dicts: view, seed, things, positions,
    relation; see :class:`cliport.pretrain.render.Crop`)."""

    images: np.ndarray
    meta: list[dict[str, Any]]

    def __len__(self) -> int:
        return len(self.meta)


@dataclass
class SceneMaps:
    """Whole scenes of one split (:class:`cliport.pretrain.render.SceneMap`): ``color`` (N, H, W, 3) uint8,
    ``labels`` (N, H, W) uint8 and ``things`` (N lists of [kind, noun, color]), in seed order."""

    color: np.ndarray
    labels: np.ndarray
    things: list[list[list[Any]]]

    def __len__(self) -> int:
        return len(self.things)


def shard_seeds(split: str, n_scenes: int) -> list[tuple[int, int]]:
    """(first, last) seeds of each shard holding the first ``n_scenes`` scenes of ``split`` (last included)."""
    first = FIRST_SEED[split]
    return [(first + k, first + min(k + SCENES_PER_SHARD, n_scenes) - 1) for k in range(0, n_scenes, SCENES_PER_SHARD)]


def shard_path(folder: str, split: str, seeds: tuple[int, int]) -> str:
    return os.path.join(folder, split, f"seeds-{seeds[0]:06d}-{seeds[1]:06d}.npz")


def _settings(crop_px: int, camera_scale: float, renderer_kind: str) -> dict[str, Any]:
    return {"format": CACHE_FORMAT, "crop_px": crop_px, "camera_scale": camera_scale, "renderer": renderer_kind}


def check_manifest(folder: str, crop_px: int, camera_scale: float, renderer_kind: str) -> None:
    """Write the folder's manifest, or ConfigError in one line if it holds crops rendered otherwise."""
    path = os.path.join(folder, "manifest.json")
    wanted = _settings(crop_px, camera_scale, renderer_kind)
    if os.path.exists(path):
        found = read_json(path)
        changed = sorted(k for k, v in wanted.items() if found.get(k) != v)
        if changed:
            detail = ", ".join(f"{k} {found.get(k)!r} there, {wanted[k]!r} here" for k in changed)
            raise ConfigError(f"{folder} holds crops rendered with other settings ({detail}): pass another cache dir")
        return
    write_json(path, wanted)


# ---------------------------------------------------------------------- rendering, in this process or workers
_RENDERER: Any = None


def _init_worker(camera_scale: float, crop_px: int, renderer: str) -> None:
    global _RENDERER
    from cliport.pretrain.render import SceneRenderer

    _RENDERER = SceneRenderer(camera_scale, crop_px, renderer)


def _render_shard(path: str, seeds: tuple[int, int]) -> tuple[int, str]:
    """Render the scenes ``seeds`` (first, last) into ``path``; (crops written, renderer kind)."""
    scenes = [_RENDERER.render(seed) for seed in range(seeds[0], seeds[1] + 1)]
    crops = [crop for scene_crops, _ in scenes for crop in scene_crops]  # scene order, then each scene's order
    maps = [scene_map for _, scene_map in scenes]
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        images=np.stack([c.image for c in crops]),
        meta=_json_bytes([crop.meta() for crop in crops]),
        map_color=np.stack([m.color for m in maps]),
        map_labels=np.stack([m.labels for m in maps]),
        map_things=_json_bytes([m.things for m in maps]),
    )
    write_bytes(path, buffer.getvalue())
    return len(crops), str(_RENDERER.renderer_kind)


def render_cache(
    folder: str,
    scenes: dict[str, int],
    crop_px: int = 64,
    camera_scale: float = 0.5,
    renderer: str = "auto",
    workers: int = 1,
    progress: bool = True,
) -> dict[str, Any]:
    """Render the shards of ``scenes`` (split -> number of scenes) that ``folder`` lacks; a summary of what was done.

    ``workers`` simulator processes render shards in parallel (1: this process). The manifest is checked (and
    written) before anything is rendered: the renderer kind ``renderer`` gives here must be the folder's.
    """
    from cliport.env.config import expected_renderer

    for split in scenes:
        if split not in SPLITS:
            raise ConfigError(f"unknown crop split {split!r}: one of {', '.join(SPLITS)}")
    check_manifest(folder, crop_px, camera_scale, expected_renderer(renderer))
    missing = [
        (shard_path(folder, split, seeds), seeds)
        for split, n in scenes.items()
        for seeds in shard_seeds(split, n)
        if not os.path.exists(shard_path(folder, split, seeds))
    ]
    total = sum(last - first + 1 for _, (first, last) in missing)
    bar = tqdm(total=total, desc="rendering scenes", unit="scene", disable=not progress or not missing)
    n_crops = 0
    try:
        if missing and workers <= 1:
            _init_worker(camera_scale, crop_px, renderer)
            for path, seeds in missing:
                n_crops += _render_shard(path, seeds)[0]
                bar.update(seeds[1] - seeds[0] + 1)
        elif missing:
            ctx = mp.get_context("spawn")
            with cf.ProcessPoolExecutor(
                min(workers, len(missing)),
                mp_context=ctx,
                initializer=_init_worker,
                initargs=(camera_scale, crop_px, renderer),
            ) as pool:
                futures = {pool.submit(_render_shard, path, seeds): seeds for path, seeds in missing}
                for future in cf.as_completed(futures):
                    n_crops += future.result()[0]
                    first, last = futures[future]
                    bar.update(last - first + 1)
    finally:
        bar.close()
        _close_renderer()
    return {"rendered_scenes": total, "rendered_crops": n_crops, "shards": len(missing)}


def _close_renderer() -> None:
    global _RENDERER
    if _RENDERER is not None:
        _RENDERER.close()
        _RENDERER = None


def _json_bytes(value: Any) -> np.ndarray:
    return np.frombuffer(json.dumps(value).encode(), np.uint8)


_JSON = ("meta", "map_things")  # the keys stored as UTF-8 JSON


def _read_shards(folder: str, split: str, n_scenes: int, keys: tuple[str, ...]) -> list[dict[str, Any]]:
    """Of each shard of the first ``n_scenes`` scenes of ``split``: ``keys`` (arrays; JSON ones decoded)."""
    shards = []
    for seeds in shard_seeds(split, n_scenes):
        path = shard_path(folder, split, seeds)
        if not os.path.exists(path):
            raise ConfigError(f"{folder} lacks the crops of {split} scenes {seeds[0]}-{seeds[1]}: render them first")
        with np.load(path, allow_pickle=False) as data:
            shards.append({k: json.loads(data[k].tobytes().decode()) if k in _JSON else data[k] for k in keys})
    if not shards:
        raise ConfigError(f"no {split} scenes asked for: at least one is needed")
    return shards


def load_crops(folder: str, split: str, n_scenes: int) -> CropSet:
    """The crops of the first ``n_scenes`` scenes of ``split`` (rendered by :func:`render_cache`), in seed order."""
    shards = _read_shards(folder, split, n_scenes, ("images", "meta"))
    return CropSet(np.concatenate([s["images"] for s in shards]), [m for s in shards for m in s["meta"]])


def load_scene_maps(folder: str, split: str, n_scenes: int) -> SceneMaps:
    """The maps of the first ``n_scenes`` scenes of ``split`` (rendered by :func:`render_cache`), in seed order."""
    shards = _read_shards(folder, split, n_scenes, ("map_color", "map_labels", "map_things"))
    return SceneMaps(
        np.concatenate([s["map_color"] for s in shards]),
        np.concatenate([s["map_labels"] for s in shards]),
        [t for s in shards for t in s["map_things"]],
    )
