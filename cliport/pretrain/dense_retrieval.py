"""Dense retrieval on the lesson's scenes: does an encoder's text-aligned map find the block a colour word names?

For each scene of a put-one-block-in-bowl-* task, the frozen encoder reads the top-down colour map the agents read
(resized by ``scale``), :func:`~cliport.models.encoders.dense_clip.dense_embeddings` gives its embedding at every
trunk position, and each of the scene's three block colours is captioned as the pretraining probe captions it
("a red block"). The caption's similarity map, resized to the map, is averaged over each block's pixels (the
oracle camera's object ids); the caption is **found** when the block it names scores highest of the three. That is
the pick a policy reading only this map would make for a swapped instruction: chance is one in three. Seen and
unseen colours (:data:`~cliport.pretrain.vocabulary.UNSEEN_COLORS`) are counted apart.

With a bank (``bank_colors``), each map is the caption's probability against the bank's captions instead of its
cosine (:func:`~cliport.models.encoders.dense_clip.bank_probability`, as agents with ``similarity_bank`` read it):
a block and a bowl caption of each bank colour, e.g. the seen palette, the words a policy's demos would show.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from cliport.evaluation.instruction_following import lesson_task
from cliport.models.encoders.base import TRUNK_STRIDES
from cliport.models.encoders.clip_encoder import FrozenCLIP
from cliport.models.encoders.dense_clip import bank_probability, instruction_phrases, similarity_map
from cliport.pretrain.vocabulary import UNSEEN_COLORS, probe_color_caption

STRIDE = TRUNK_STRIDES[-1]  # the trunk's last level: the image is padded to a multiple of it


def caption_maps(
    encoder: FrozenCLIP, color: np.ndarray, captions: list[str], scale: float, bank: list[str] | None = None
) -> torch.Tensor:
    """A top-down colour map (H, W, 3) uint8 and C captions -> their cosine-similarity maps (C, H, W), or with
    ``bank`` (texts) each caption's probability against it, the image read at ``scale`` times its size (padded
    to a multiple of the trunk's stride) and the maps resized back."""
    h, w = color.shape[:2]
    rgb = torch.from_numpy(np.ascontiguousarray(color)).permute(2, 0, 1)[None].float() / 255.0
    size = (max(1, round(h * scale)), max(1, round(w * scale)))
    rgb = F.interpolate(rgb, size=size, mode="bilinear", align_corners=False, antialias=True)
    pad = (-size[1] % STRIDE, -size[0] % STRIDE)
    rgb = F.pad(rgb, (0, pad[0], 0, pad[1]))
    with torch.no_grad():
        dense = encoder.dense_embeddings(encoder.image_features(rgb)[-1])  # (1, E, h', w')
        texts = encoder.sentence_features(captions)[None]
        if bank:
            entries = encoder.sentence_features(bank)
            valid = torch.ones(len(bank), dtype=torch.bool)
            maps = bank_probability(dense, texts, entries, valid, encoder.logit_scale())  # (1, C, h', w')
        else:
            maps = similarity_map(dense, texts)
        maps = F.interpolate(maps, size=rgb.shape[-2:], mode="bilinear", align_corners=False)
    return F.interpolate(maps[..., : size[0], : size[1]], size=(h, w), mode="bilinear", align_corners=False)[0]


def block_scores(maps: torch.Tensor, masks: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Caption maps (C, H, W) and each block's pixels (H, W) bool, none empty -> per block, its mean under each
    map (C,)."""
    return {name: maps[:, torch.from_numpy(mask)].mean(dim=1) for name, mask in masks.items()}


def found(scores: dict[str, torch.Tensor]) -> dict[str, bool]:
    """Per block, its mean under each caption (B,), the c-th caption naming the c-th block -> per block, whether it
    scores highest of the scene's blocks under the caption that names it."""
    names = list(scores)
    table = torch.stack([scores[name] for name in names])  # (blocks, captions)
    return {name: names[int(table[:, c].argmax())] == name for c, name in enumerate(names)}


def dense_retrieval(
    encoder: FrozenCLIP,
    task_name: str,
    seeds: Iterable[int],
    scale: float = 1.0,
    camera_scale: float = 1.0,
    mode: str = "test",
    bank_colors: Iterable[str] = (),
) -> dict[str, Any]:
    """Each scene of ``seeds``: every block colour captioned and looked for (module docstring). Returns
    ``{"seen": {"found", "n", "rate"}, "unseen": {...}, "scenes": n, "scale": scale, "records": [...]}``."""
    bank = [probe_color_caption(c, noun) for c in bank_colors for noun in ("block", "bowl")]

    def maps(obs: dict[str, np.ndarray], task: Any, names: list[str]) -> torch.Tensor:
        return caption_maps(encoder, obs["color"], [probe_color_caption(name) for name in names], scale, bank)

    report = _retrieval(task_name, seeds, camera_scale, mode, maps)
    return {**report, "scale": scale, "bank": sorted(set(bank_colors))}


def agent_retrieval(
    agent: Any, task_name: str, seeds: Iterable[int], camera_scale: float = 1.0, mode: str = "test"
) -> dict[str, Any]:
    """Dense retrieval through an agent's own maps (a two_stream agent with ``similarity_maps``): for each block of
    each scene, the map of the phrase naming it ("the pink block") that the pick net reads
    (``agent.similarity_heatmaps``) for the scene's instruction with that block put in; found as in
    :func:`dense_retrieval`. Same report, without ``scale`` and ``bank``."""

    def maps(obs: dict[str, np.ndarray], task: Any, names: list[str]) -> torch.Tensor:
        out = []
        for name in names:
            instruction = task.instruction_for(name, task.goal_bowl)
            heatmaps = agent.similarity_heatmaps(obs, instruction)
            phrase = next((p for p in instruction_phrases(instruction) if name in p.split()), None)
            if phrase not in heatmaps:
                raise ValueError(f"{agent.name} has no similarity map of a phrase naming the {name} block")
            out.append(torch.from_numpy(heatmaps[phrase]).float())
        return torch.stack(out)

    return _retrieval(task_name, seeds, camera_scale, mode, maps)


def _retrieval(
    task_name: str,
    seeds: Iterable[int],
    camera_scale: float,
    mode: str,
    maps: Callable[[dict[str, np.ndarray], Any, list[str]], torch.Tensor],
) -> dict[str, Any]:
    """Each scene of ``seeds``: ``maps(obs, task, block names)`` (C, H, W) scored per block (:func:`found`),
    counted seen and unseen apart."""
    from cliport.env.environment import EnvConfig, Environment

    task = lesson_task(task_name, mode, "dense retrieval")
    records: list[dict[str, Any]] = []
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        for seed in seeds:
            obs = env.reset(seed=int(seed))
            _, ids = env.oracle_heightmap()
            if obs["color"].shape[:2] != ids.shape:
                raise ValueError(f"the colour map {obs['color'].shape[:2]} and the object ids {ids.shape} differ")
            masks = {name: ids == body for name, body in task.block_colors.items()}
            masks = {name: mask for name, mask in masks.items() if mask.any()}  # a block the camera cannot see
            scores = block_scores(maps(obs, task, list(masks)), masks)
            for name, ok in found(scores).items():
                records.append({"seed": int(seed), "color": name, "unseen": name in UNSEEN_COLORS, "found": ok})
    out: dict[str, Any] = {}
    for part, unseen in (("seen", False), ("unseen", True)):
        rows = [r for r in records if r["unseen"] is unseen]
        hits = sum(r["found"] for r in rows)
        out[part] = {"found": hits, "n": len(rows), "rate": round(hits / len(rows), 4) if rows else None}
    return {**out, "scenes": len({r["seed"] for r in records}), "records": records}
