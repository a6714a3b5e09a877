"""The frozen encoder keeps the trunk features of recent CPU images (FrozenEncoder.image_features)."""

from collections.abc import Callable

import pytest
import torch

from cliport.models.encoders.base import RECENT_IMAGES
from cliport.models.encoders.clip_encoder import FrozenCLIP, load_clip


@pytest.fixture()
def counted() -> tuple[FrozenCLIP, list[tuple[int, ...]]]:
    """A random CLIP whose trunk records the shape of every batch it runs on."""
    clip = load_clip("random")
    shapes: list[tuple[int, ...]] = []
    trunk: Callable[[torch.Tensor], list[torch.Tensor]] = clip._trunk

    def recording(rgb: torch.Tensor) -> list[torch.Tensor]:
        shapes.append(tuple(rgb.shape))
        return trunk(rgb)

    clip._trunk = recording  # type: ignore[method-assign]
    return clip, shapes


def _uncached(clip: FrozenCLIP, rgb: torch.Tensor) -> list[torch.Tensor]:
    return [f.float() for f in FrozenCLIP._trunk(clip, rgb.float())]


def test_an_equal_image_reuses_its_features_and_another_does_not(counted) -> None:
    clip, shapes = counted
    gen = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, 64, 64, generator=gen)
    first = clip.image_features(image)
    again = clip.image_features(image.clone())
    assert len(shapes) == 1
    assert all(a is b for a, b in zip(first, again, strict=True))
    for got, want in zip(first, _uncached(clip, image), strict=True):
        assert torch.equal(got, want)

    changed = image.clone()
    changed[0, 1, 5, 7] += 1e-3
    other = clip.image_features(changed)
    assert len(shapes) == 2
    assert not torch.equal(other[0], first[0])


def test_only_the_most_recent_images_are_kept(counted) -> None:
    clip, shapes = counted
    images = [torch.full((1, 3, 32, 32), i / 10) for i in range(RECENT_IMAGES + 1)]
    for image in images:
        clip.image_features(image)
    clip.image_features(images[-1])
    assert len(shapes) == RECENT_IMAGES + 1
    clip.image_features(images[0])  # pushed out by the RECENT_IMAGES after it
    assert len(shapes) == RECENT_IMAGES + 2


def test_a_batch_of_one_repeated_image_runs_the_trunk_once(counted) -> None:
    clip, shapes = counted
    image = torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(1))
    feats = clip.image_features(image.expand(6, -1, -1, -1).clone())
    assert shapes == [(1, 3, 64, 96)]
    assert [f.shape[0] for f in feats] == [6] * 5
    for got, want in zip(feats, _uncached(clip, image), strict=True):
        assert torch.equal(got, want.expand_as(got))

    mixed = torch.cat([image, image, image * 0.5])
    clip.image_features(mixed)
    assert shapes[-1] == (3, 3, 64, 96)


def test_new_weights_or_dtype_drop_the_kept_features(counted) -> None:
    clip, shapes = counted
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(2))
    before = clip.image_features(image)
    state = {k: v * 1.5 if v.is_floating_point() else v for k, v in clip.state_dict().items()}
    clip.load_state_dict(state)
    after = clip.image_features(image)
    assert len(shapes) == 2
    assert not torch.equal(after[-1], before[-1])
    for got, want in zip(after, _uncached(clip, image), strict=True):
        assert torch.equal(got, want)

    clip.set_image_dtype(torch.bfloat16)
    clip.image_features(image)
    clip.set_image_dtype(torch.float32)
    clip.image_features(image)
    assert len(shapes) == 4


def test_features_under_other_statistics_are_never_kept(counted) -> None:
    clip, shapes = counted
    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(3))
    stats = {name: value.clone() for name, value in clip.norm_stats().items()}
    clip.image_features(image, stats)
    clip.image_features(image, stats)
    assert len(shapes) == 2
