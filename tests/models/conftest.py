"""Fixtures shared by the model tests."""

import pytest

from cliport.models.encoders.clip_encoder import FrozenCLIP, load_clip


@pytest.fixture(scope="module")
def clip() -> FrozenCLIP:
    """The seeded random CLIP RN50 (read-only in the tests that take it)."""
    return load_clip("random")
