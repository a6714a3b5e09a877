"""A torch Dataset of demonstration steps for training pick-and-place agents."""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from cliport.data import augment as augment_ops
from cliport.data.episode_io import (
    EpisodeData,
    dataset_dir,
    episode_path,
    existing_seeds,
    load_episode,
    read_meta,
    read_poses,
)
from cliport.env import heightmap as hm
from cliport.errors import UnknownNameError, UserError


class DatasetError(UserError, ValueError):
    """The requested data is missing or unusable; the message names the path."""


#: Two oracle poses closer than this (metres, in x and y) are on the same object: a block is 4 cm wide (5.7 cm
#: corner to corner), a bowl 12 cm.
SAME_OBJECT_M = 0.05


class DemoDataset(Dataset):
    """Steps of oracle episodes of one task or a multi-task group.

    Each sample is a random step (index -> (episode, step); shuffle in the DataLoader) with the SE(2)
    augmentation applied to the image and both action poses alike:
      color (320, 160, 3) uint8, height (320, 160) float32 metres, pose0 (7,) and pose1 (7,) float64
      pick and place poses (xyz + quaternion xyzw) in the frame of the augmented image, lang str, task str.
    Turning poses into training targets (pixels, rotation bins) is the agent's business.
    ``n_demos`` episodes per task are a subset chosen with ``seed`` (the same seed, the same subset).
    ``rotation_aug`` is the standard deviation (degrees) of the augmentation's rotation; 0 keeps the
    recorded orientation and only shifts the image. ``aug_pivot`` and ``aug_interpolation`` name the
    rotation's pivot and the warp's interpolation (:data:`~cliport.data.augment.PIVOTS`,
    :data:`~cliport.data.augment.INTERPOLATIONS`; a training recipe chooses them).
    ``every_instruction``: every instruction the episode files record for each step (the recorded one and
    the variants of ``cliport-demos --every-instruction``) is a sample of its own, with the oracle's poses
    for it; the image is the step's own.
    """

    def __init__(
        self,
        data_dir: str,
        task: str,
        mode: str = "train",
        n_demos: int | None = None,
        seed: int = 0,
        augment: bool = True,
        cache_episodes: int = 128,
        rotation_aug: float = math.degrees(augment_ops.ANGLE_STD),
        aug_pivot: str = "half_size",
        aug_interpolation: str = "nearest",
        every_instruction: bool = False,
    ):
        from cliport import tasks

        try:
            names = tasks.resolve(task)
        except UnknownNameError as e:
            raise DatasetError(str(e)) from e
        if not rotation_aug >= 0:
            raise DatasetError(f"rotation_aug must be >= 0 degrees, got {rotation_aug}")
        if aug_pivot not in augment_ops.PIVOTS:
            raise DatasetError(f"aug_pivot must be one of {', '.join(augment_ops.PIVOTS)}, got {aug_pivot!r}")
        if aug_interpolation not in augment_ops.INTERPOLATIONS:
            raise DatasetError(
                f"aug_interpolation must be one of {', '.join(augment_ops.INTERPOLATIONS)}, got {aug_interpolation!r}"
            )
        self.augment = augment
        self.aug_pivot = aug_pivot
        self.aug_interpolation = aug_interpolation
        self.rotation_std = math.radians(rotation_aug)
        self.cache_episodes = cache_episodes
        self.files: list[tuple[str, str]] = []  # (task, path)
        for name in names:
            folder = dataset_dir(data_dir, name, mode)
            if not os.path.isdir(folder):
                raise DatasetError(
                    f"no demonstrations for {name} ({mode}) in {folder}: run "
                    f"`cliport-demos --task {name} --mode {mode} --n N --data-dir {data_dir}`"
                )
            seeds = existing_seeds(folder)
            if n_demos is not None:
                if n_demos < 1:
                    raise DatasetError(f"n_demos must be >= 1, got {n_demos}")
                if n_demos > len(seeds):
                    raise DatasetError(f"{folder} has {len(seeds)} episodes but n_demos={n_demos} were asked for")
                pick = np.random.default_rng(seed).choice(len(seeds), size=n_demos, replace=False)
                seeds = [seeds[i] for i in sorted(pick)]
            elif not seeds:
                raise DatasetError(f"{folder} holds no episodes")
            self.files += [(name, episode_path(folder, s)) for s in seeds]
        self.index: list[tuple[int, int, int]] = []  # (episode, step, instruction)
        self._instructions: set[str] = set()
        for episode, (_, path) in enumerate(self.files):
            table = _instruction_table(path)
            if every_instruction and any(len(row) == 1 for row in table):
                raise DatasetError(
                    f"{path} records one instruction per step; every_instruction needs demos made with "
                    f"`cliport-demos --every-instruction` (the quickstart's --language makes them)"
                )
            for t, row in enumerate(table):
                chosen = row if every_instruction else row[:1]
                self.index += [(episode, t, k) for k in range(len(chosen))]
                self._instructions.update(lang for lang in chosen if lang)
        self._cache: OrderedDict[int, EpisodeData] = OrderedDict()
        self._rng: np.random.Generator | None = None

    def __len__(self) -> int:
        return len(self.index)

    def episode(self, e: int) -> EpisodeData:
        if e in self._cache:
            self._cache.move_to_end(e)
            return self._cache[e]
        data = load_episode(self.files[e][1])
        self._cache[e] = data
        if len(self._cache) > self.cache_episodes:
            self._cache.popitem(last=False)
        return data

    def instructions(self) -> list[str]:
        """The distinct instructions of the samples, sorted (empty strings left out)."""
        return sorted(self._instructions)

    def recorded_camera_scales(self) -> dict[str, float | None]:
        """Per task, the camera_scale its first episode file records (None for files that predate it)."""
        return self._recorded("camera_scale")

    def recorded_renderers(self) -> dict[str, str | None]:
        """Per task, the renderer ("egl" or "tiny") its first episode file records (None for files that
        predate the record, and for imported real demonstrations)."""
        return self._recorded("renderer")

    def _recorded(self, key: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for task, path in self.files:
            if task not in out:
                out[task] = read_meta(path).get(key)
        return out

    def _generator(self) -> np.random.Generator:
        # Seeded from torch so that DataLoader workers differ and torch.manual_seed reproduces a run.
        if self._rng is None:
            self._rng = np.random.default_rng(torch.initial_seed() % 2**63)
        return self._rng

    def contrasting(self) -> list[list[int]]:
        """Per sample, the other samples of its scene whose instruction asks for another pick and another place
        (another block into the other bowl): picks and places more than :data:`SAME_OBJECT_M` apart in x, y (an
        oracle picks a random point of the object). The pairs :class:`~cliport.train.loader.ContrastPairSampler`
        draws; empty lists without ``every_instruction``."""
        poses = [read_poses(path) for _, path in self.files]
        scenes: dict[tuple[int, int], list[int]] = {}
        for j, (e, t, _) in enumerate(self.index):
            scenes.setdefault((e, t), []).append(j)
        partners: list[list[int]] = []
        for e, t, k in self.index:
            pick, place = poses[e][0][t], poses[e][1][t]
            partners.append([
                j
                for j in scenes[e, t]
                if np.linalg.norm(pick[(k2 := self.index[j][2]), :2] - pick[k, :2]) > SAME_OBJECT_M
                and np.linalg.norm(place[k2, :2] - place[k, :2]) > SAME_OBJECT_M
            ])  # fmt: skip
        return partners

    def __getitem__(self, item: int | tuple[int, int]) -> dict[str, Any]:
        """Sample ``item``: an index, augmented from the dataset's generator, or (index, seed), augmented from a
        generator of that seed (a pair of samples with one seed gets the same transform)."""
        if isinstance(item, tuple):
            i, seed = item
            return self.sample(i, self.augment, np.random.default_rng(seed))
        return self.sample(item, self.augment)

    def sample(self, i: int, augment: bool, rng: np.random.Generator | None = None) -> dict[str, Any]:
        """Sample ``i``, with the random SE(2) augmentation or as recorded (``augment`` False draws nothing). The
        transform is drawn from the dataset's generator and keeps the sample's pick and place in view; with
        ``rng``, from ``rng`` keeping the targets of every instruction of the scene in view, so that the samples
        of one scene get the same transform from generators of one seed."""
        e, t, k = self.index[i]
        ep = self.episode(e)
        color, height = ep.color[t], ep.height[t]
        lang, pose0, pose1 = ep.instruction(t, k)
        pose0, pose1 = pose0.copy(), pose1.copy()
        if augment:
            if rng is None:
                rng, kept = self._generator(), [(pose0, pose1)]
            else:
                kept = [ep.instruction(t, j)[1:] for j in range(1 + len(ep.variant_lang[t] if ep.variant_lang else []))]
            points = [hm.xyz_to_pix(pose[:3]) for pair in kept for pose in pair]
            m = augment_ops.sample_se2(rng, height.shape, points, angle_std=self.rotation_std, pivot=self.aug_pivot)
            color, height = augment_ops.warp_observation(color, height, m, self.aug_interpolation)
            pose0, pose1 = augment_ops.transform_pose(m, pose0), augment_ops.transform_pose(m, pose1)
        return {
            "color": np.ascontiguousarray(color),
            "height": np.ascontiguousarray(height, dtype=np.float32),
            "pose0": pose0,
            "pose1": pose1,
            "lang": lang,
            "task": self.files[e][0],
        }


def _instruction_table(path: str) -> list[list[str]]:
    """Per step of an episode file, its recorded instruction and variants, read from its small arrays only
    (see check_episode_file)."""
    from cliport.data.episode_io import EpisodeFileError, read_instructions

    try:
        return read_instructions(path)
    except EpisodeFileError as e:
        raise DatasetError(f"{e}; re-running cliport-demos for this task and mode replaces it") from None
