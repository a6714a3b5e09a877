"""The probe: zero-shot colour and shape retrieval on held-out rendered scenes, before any policy is trained.

Each crop of a probe scene (seeds never trained on) that shows one object alone is matched against a fixed set of
captions, and counts as right when the most similar caption names it:

- **colors**: crops of a block, against "a {colour} block" for all 11 colours (chance 1/11); reported for the
  colours CLIPort trains its policies on (``seen``) and those its ``-unseen-colors`` splits hold out (``unseen``).
- **bowl_colors**: the same for bowls ("a {colour} bowl").
- **shapes**: crops of a kit shape, against "a {label}" for the 20 kit shapes (chance 1/20); ``seen`` are the
  kitting tasks' train shapes, ``unseen`` their held-out ones.

Each is also reported per view (top-down, oblique). The weights are loaded through the agents' own path
(:func:`~cliport.models.encoders.clip_weights.build_clip_model`): ``random`` is the seeded random model an agent
with random CLIP freezes, a file is read as ``--clip-weights FILE`` reads it.
"""

from __future__ import annotations

import os
from collections import defaultdict
from typing import Any

import numpy as np
import torch

from cliport.errors import ConfigError
from cliport.models.encoders.clip_registry import model_config, pretrained_tags
from cliport.models.encoders.clip_tokenizer import load_tokenizer
from cliport.models.encoders.clip_weights import build_clip_model
from cliport.pretrain.batches import resize_images
from cliport.pretrain.cache import CropSet, SceneMaps
from cliport.pretrain.vocabulary import COLOR_NAMES, UNSEEN_COLORS, probe_color_caption, probe_shape_caption
from cliport.tasks.kit_shapes import SHAPES, TEST_SHAPES

SHAPE_LABELS: tuple[str, ...] = tuple(shape.label for shape in SHAPES)
UNSEEN_SHAPES: tuple[str, ...] = tuple(SHAPES[i].label for i in TEST_SHAPES)


def image_size(model_name: str) -> int:
    """The side of the images the model's image tower embeds (its config's ``image_size``)."""
    size = model_config(model_name)["vision_cfg"]["image_size"]
    return int(size[0] if isinstance(size, list | tuple) else size)


def normalise(model: Any, images: torch.Tensor) -> torch.Tensor:
    """RGB (N, 3, H, W) in [0, 1] -> the model's input: minus its ``visual.image_mean``, over its ``image_std``
    (what :class:`~cliport.models.encoders.clip_encoder.FrozenCLIP` does before its trunk)."""
    mean = torch.tensor(model.visual.image_mean, device=images.device).view(1, 3, 1, 1)
    std = torch.tensor(model.visual.image_std, device=images.device).view(1, 3, 1, 1)
    return (images - mean) / std


@torch.no_grad()
def embed_images(model: Any, images: torch.Tensor, device: str, chunk: int = 256) -> torch.Tensor:
    """(N, 3, S, S) uint8 -> (N, D) L2-normalised image embeddings (the model in eval mode)."""
    out = [
        model.encode_image(normalise(model, part.to(device).float() / 255), normalize=True).float().cpu()
        for part in images.split(chunk)
    ]
    return torch.cat(out)


@torch.no_grad()
def embed_texts(model: Any, model_name: str, texts: list[str], device: str) -> torch.Tensor:
    """(T,) captions -> (T, D) L2-normalised text embeddings."""
    tokens = load_tokenizer(model_name)(texts).to(device)
    return model.encode_text(tokens, normalize=True).float().cpu()


def _alone(meta: dict[str, Any], kind: str) -> bool:
    return meta.get("relation") is None and len(meta["things"]) == 1 and meta["things"][0][0] == kind


def _scores(right: list[bool], groups: list[str], views: list[str]) -> dict[str, Any]:
    by: dict[str, dict[str, list[bool]]] = {"group": defaultdict(list), "view": defaultdict(list)}
    for ok, group, view in zip(right, groups, views, strict=True):
        by["group"][group].append(ok)
        by["view"][view].append(ok)

    def rate(values: list[bool]) -> dict[str, Any]:
        return {"top1": round(float(np.mean(values)), 4) if values else None, "n": len(values)}

    return {
        **{group: rate(by["group"][group]) for group in ("seen", "unseen")},
        "all": rate(right),
        "by_view": {view: rate(values) for view, values in sorted(by["view"].items())},
    }


def _retrieval(
    images: torch.Tensor, metas: list[dict[str, Any]], kind: str, names: tuple[str, ...], captions: torch.Tensor
) -> tuple[list[bool], list[str], list[str], list[str]]:
    """For the crops showing one ``kind`` alone: is the best caption its own? (right, truth, view, predicted)."""
    picked = [i for i, m in enumerate(metas) if _alone(m, kind)]
    if not picked:
        return [], [], [], []
    best = (images[picked] @ captions.T).argmax(dim=1).tolist()
    truth = [metas[i]["things"][0][2 if kind != "shape" else 1] for i in picked]
    predicted = [names[k] for k in best]
    return [p == t for p, t in zip(predicted, truth, strict=True)], truth, [metas[i]["view"] for i in picked], predicted


def probe_model(model: Any, model_name: str, crops: CropSet, device: str = "cpu") -> dict[str, Any]:
    """The probe's scores of an open_clip model on the crops of probe scenes (see the module docstring)."""
    was_training = model.training
    model.eval()
    try:
        images = embed_images(model, resize_images(crops.images, image_size(model_name)), device)
        results: dict[str, Any] = {}
        for key, kind, noun in (("colors", "block", "block"), ("bowl_colors", "bowl", "bowl")):
            captions = embed_texts(model, model_name, [probe_color_caption(c, noun) for c in COLOR_NAMES], device)
            right, truth, views, _ = _retrieval(images, crops.meta, kind, COLOR_NAMES, captions)
            groups = ["unseen" if t in UNSEEN_COLORS else "seen" for t in truth]
            results[key] = {**_scores(right, groups, views), "chance": round(1 / len(COLOR_NAMES), 4)}
        captions = embed_texts(model, model_name, [probe_shape_caption(s) for s in SHAPE_LABELS], device)
        right, truth, views, _ = _retrieval(images, crops.meta, "shape", SHAPE_LABELS, captions)
        groups = ["unseen" if t in UNSEEN_SHAPES else "seen" for t in truth]
        results["shapes"] = {**_scores(right, groups, views), "chance": round(1 / len(SHAPE_LABELS), 4)}
    finally:
        model.train(was_training)
    return results


def check_weights_source(source: str, model_name: str) -> None:
    """ConfigError in one line unless ``source`` is "random", a pretrained tag of the model or an existing file."""
    if source != "random" and source not in pretrained_tags(model_name) and not os.path.isfile(source):
        raise ConfigError(f"--probe {source}: not 'random', a pretrained tag of {model_name} nor an existing file")


def probe_weights(
    source: str,
    model_name: str,
    crops: CropSet,
    device: str = "cpu",
    maps: SceneMaps | None = None,
    scale: float = 2.0,
) -> dict[str, Any]:
    """The probe of weights ``source`` ("random", a file, a pretrained tag) of ``model_name``, loaded as an agent
    loads them; the result names both. With ``maps`` (whole probe scenes), also ``dense``: their pixels' colour
    retrieval read at ``scale`` (:func:`~cliport.pretrain.dense.dense_probe`)."""
    from cliport.pretrain.dense import dense_probe

    model = build_clip_model(source, model_name).to(device)
    result = {"weights": source, "semantic_encoder": model_name, **probe_model(model, model_name, crops, device)}
    if maps is not None:
        result["dense"] = {"scale": scale, **dense_probe(model, model_name, maps, scale, device)}
    return result
