"""Damaged episode files: one short message naming the file, never numpy's advice to load unsafely."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cliport.data.episode_io import EpisodeFileError, check_episode_file, load_episode


@pytest.fixture
def episode(tmp_path: Path, make_synthetic_dataset) -> Path:
    folder = Path(make_synthetic_dataset(str(tmp_path), n_episodes=1))
    return folder / "000000.npz"


def _damage(path: Path, kind: str) -> None:
    data = path.read_bytes()
    if kind == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif kind == "random-bytes":
        path.write_bytes(np.random.default_rng(0).bytes(5000))
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "foreign-npz":
        np.savez(path, weights=np.zeros(3))
    elif kind == "middle":  # intact length and directory, damaged compressed colour data
        with zipfile.ZipFile(path) as z:
            info = z.getinfo("color.npy")
        start = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
        damaged = bytearray(data)
        damaged[start : start + 64] = bytes(64)
        path.write_bytes(bytes(damaged))


def test_intact_file_passes_both_checks(episode: Path) -> None:
    assert check_episode_file(str(episode)) == len(load_episode(str(episode))) == 2


@pytest.mark.parametrize("kind", ["truncated", "random-bytes", "empty", "foreign-npz"])
def test_broken_file_is_named_with_a_short_reason(episode: Path, kind: str) -> None:
    _damage(episode, kind)
    for read in (check_episode_file, load_episode):
        with pytest.raises(EpisodeFileError) as err:
            read(str(episode))
        message = str(err.value)
        assert message.startswith(f"corrupt episode file {episode}: truncated or not a demo file"), message
        assert "unsafe" not in message and "pickle" not in message


def test_damage_inside_the_images_is_found_by_load_only(episode: Path) -> None:
    _damage(episode, "middle")
    assert check_episode_file(str(episode)) == 2  # the cheap check reads only the small arrays
    with pytest.raises(EpisodeFileError, match=f"corrupt episode file {episode}: the 'color' array is damaged"):
        load_episode(str(episode))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(EpisodeFileError, match="episode file not found: .*nope.npz"):
        check_episode_file(os.path.join(tmp_path, "nope.npz"))


def test_steps_must_record_the_same_number_of_instruction_variants(tmp_path: Path) -> None:
    from cliport.data.episode_io import save_episode

    obs = {"color": np.zeros((4, 2, 3), np.uint8), "height": np.zeros((4, 2), np.float32)}
    action = {"pose0": ((0.3, 0.0, 0.0), (0, 0, 0, 1)), "pose1": ((0.4, 0.0, 0.0), (0, 0, 0, 1))}
    step = {"obs": obs, "action": action, "reward": 0.5, "lang_goal": "a"}
    steps = [{**step, "variants": [("b", action)]}, step]
    with pytest.raises(ValueError, match=r"same number of instruction variants, got \[0, 1\]"):
        save_episode(str(tmp_path / "000000.npz"), steps, {"seed": 0})
    assert not list(tmp_path.iterdir())
