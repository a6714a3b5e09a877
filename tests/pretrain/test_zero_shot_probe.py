"""The probe: top-1 retrieval of the crops of held-out scenes, split by seen and unseen colours and shapes, for
weights loaded as an agent loads them."""

from __future__ import annotations

import numpy as np
import pytest

from cliport.pretrain.cache import CropSet, load_crops
from cliport.pretrain.probe import probe_model, probe_weights
from cliport.pretrain.vocabulary import UNSEEN_COLORS


def test_probe_counts_each_crop_of_one_object_in_its_group(tiny_cache: str) -> None:
    crops = load_crops(tiny_cache, "probe", 3)
    result = probe_weights("random", "cliport-RN-tiny", crops)
    assert result["weights"] == "random" and result["semantic_encoder"] == "cliport-RN-tiny"
    alone_blocks = [
        m for m in crops.meta if m["relation"] is None and len(m["things"]) == 1 and m["things"][0][0] == "block"
    ]
    colors = result["colors"]
    assert colors["all"]["n"] == len(alone_blocks) > 0
    assert colors["unseen"]["n"] == sum(m["things"][0][2] in UNSEEN_COLORS for m in alone_blocks)
    assert colors["seen"]["n"] + colors["unseen"]["n"] == colors["all"]["n"]
    assert sum(v["n"] for v in colors["by_view"].values()) == colors["all"]["n"]
    assert colors["chance"] == pytest.approx(1 / 11, abs=1e-4) and result["shapes"]["chance"] == 0.05
    assert result["shapes"]["all"]["n"] > 0


def test_a_model_that_sees_colours_scores_them(tiny_cache: str) -> None:
    """A stand-in model whose image embedding is the crop's mean colour and whose text embedding is the named
    colour's RGB (both normalised) retrieves solid-colour crops perfectly: the probe scores what it should."""
    import torch

    from cliport.pretrain.vocabulary import COLOR_NAMES
    from cliport.tasks.colors import COLORS

    class ColourModel(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.visual = type("V", (), {"image_mean": (0.0, 0.0, 0.0), "image_std": (1.0, 1.0, 1.0)})()

        def encode_image(self, images: torch.Tensor, normalize: bool = True) -> torch.Tensor:
            return torch.nn.functional.normalize(images.mean(dim=(2, 3)) - 0.5, dim=1)

        def encode_text(self, tokens: torch.Tensor, normalize: bool = True) -> torch.Tensor:
            names = [self.decode.get(tuple(t.tolist())) for t in tokens]  # shape captions name no colour
            rgb = torch.tensor([COLORS[n] if n else (128, 128, 128) for n in names], dtype=torch.float) / 255 - 0.5
            return torch.nn.functional.normalize(rgb, dim=1)

    from cliport.models.encoders.clip_tokenizer import load_tokenizer
    from cliport.pretrain.vocabulary import probe_color_caption

    model = ColourModel()
    tokenizer = load_tokenizer("cliport-RN-tiny")
    captions = [probe_color_caption(c, noun) for noun in ("block", "bowl") for c in COLOR_NAMES]
    model.decode = {tuple(tokenizer([c])[0].tolist()): c.split()[-2] for c in captions}
    images = np.stack([np.full((64, 64, 3), COLORS[c], np.uint8) for c in COLOR_NAMES])
    meta = [{"view": "top", "seed": 0, "things": [["block", "block", c]], "positions": None, "relation": None}
            for c in COLOR_NAMES]  # fmt: skip
    result = probe_model(model, "cliport-RN-tiny", CropSet(images, meta))
    assert result["colors"]["seen"] == {"top1": 1.0, "n": 7} and result["colors"]["unseen"] == {"top1": 1.0, "n": 4}
