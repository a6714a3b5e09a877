"""Fixtures shared by the agent tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(scope="module")
def two_stream_overrides() -> dict[str, object]:
    """Settings a test module's ``two_stream`` agent adds to :func:`tiny_config`'s (override to change them)."""
    return {}


@pytest.fixture(scope="module")
def two_stream(tiny_config, two_stream_overrides):
    """A tiny two_stream agent (random CLIP, seed 0), one per test module: its tests may train or change it."""
    from cliport.agents import make_agent

    torch.manual_seed(0)
    return make_agent("two_stream", tiny_config("two_stream", **two_stream_overrides))
