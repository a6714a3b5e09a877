"""A tiny crop cache rendered once per test session (6 training and 3 probe scenes, TinyRenderer), and pretraining
settings small enough for a test."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from cliport.pretrain.cache import render_cache
from cliport.pretrain.config import PretrainConfig, load_config

TRAIN_SCENES = 6
PROBE_SCENES = 3


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread() -> Iterator[None]:
    """The tiny models train on one thread: beside other work on a 2-core machine, torch's two threads waited on each
    other (measured: the learning test 99 s at two threads under a load of 4-5, 3.8 s at one)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def tiny_cache(tmp_path_factory: pytest.TempPathFactory) -> str:
    folder = str(tmp_path_factory.mktemp("crops"))
    render_cache(folder, {"train": TRAIN_SCENES, "probe": PROBE_SCENES}, renderer="cpu", workers=1, progress=False)
    return folder


@pytest.fixture(scope="session")
def tiny_config() -> Callable[..., PretrainConfig]:
    """``tiny_config(out_dir, cache_dir, **overrides)``: settings of cliport-RN-tiny on the tiny cache, a few steps
    of a small batch."""
    return make_tiny_config


@pytest.fixture
def train_scenes() -> int:
    return TRAIN_SCENES


def make_tiny_config(out_dir: str, cache_dir: str, **overrides: Any) -> PretrainConfig:
    """cliport-RN-tiny on the tiny cache, a few steps of a small batch."""
    settings: dict[str, Any] = {
        "out_dir": out_dir,
        "cache_dir": cache_dir,
        "train_scenes": TRAIN_SCENES,
        "probe_scenes": PROBE_SCENES,
        "renderer": "cpu",
        "render_workers": 1,
        "steps": 10,
        "batch_size": 32,
        "lr": 0.002,
        "warmup_steps": 2,
        "log_every": 1,
        "save_every": 5,
    }
    return load_config({**settings, **overrides})
