"""Pick-and-place agent shared by both architectures: loss, training step, acting and checkpoints."""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cliport.agents.config import TransporterOnlyConfig
from cliport.env.heightmap import pix_to_xyz
from cliport.env.transforms import yaw_to_quat
from cliport.models.clip_backbone import FrozenCLIP
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.preprocess import raw_input

CHECKPOINT_FORMAT = 1


class PickPlaceAgent(nn.Module):
    """Pick head + place head over a top-down (H, W) RGB-D observation.

    Training batch: ``color`` uint8 (B, H, W, 3), ``height`` float (B, H, W), ``pick_pix`` int64 (B, 2),
    ``place_pix`` int64 (B, 2), ``place_rot`` int64 (B,) bin of the relative yaw, ``lang`` list[str].
    """

    name = ""

    def __init__(
        self,
        config: TransporterOnlyConfig,
        pick: PickHead,
        place: PlaceHead,
        clip: FrozenCLIP | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.pick = pick
        self.place = place
        self.clip = clip

    @property
    def device(self) -> torch.device:
        return next(self.pick.parameters()).device

    def sentence_features(self, lang: list[str] | None) -> torch.Tensor | None:
        """(B, 1024) CLIP sentence features of the instructions, or None for agents without language."""
        return None

    def make_optimizer(self) -> torch.optim.Optimizer:
        """Adam over the trainable parameters at the configured learning rate."""
        return torch.optim.Adam(self.trainable_parameters(), lr=self.config.lr, foreach=True)

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def logits(
        self, x: torch.Tensor, pick_pix: torch.Tensor, lang: list[str] | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw input (B, 6, H, W), pick pixels (B, 2) -> pick logits (B, H, W), place logits (B, R, H, W)."""
        sentence = self.sentence_features(lang)
        return self.pick(x, sentence), self.place(x, pick_pix, sentence)

    def compute_loss(self, batch: dict[str, Any]) -> tuple[torch.Tensor, dict[str, float]]:
        """Cross-entropy over all pick pixels plus over all place pixels x rotations (batch mean)."""
        device = self.device
        x = raw_input(batch["color"], batch["height"]).to(device)
        pick_pix = torch.as_tensor(batch["pick_pix"], device=device).long()
        place_pix = torch.as_tensor(batch["place_pix"], device=device).long()
        place_rot = torch.as_tensor(batch["place_rot"], device=device).long()
        pick_logits, place_logits = self.logits(x, pick_pix, batch.get("lang"))
        h, w = x.shape[-2:]
        pick_target = pick_pix[:, 0] * w + pick_pix[:, 1]
        place_target = (place_rot * h + place_pix[:, 0]) * w + place_pix[:, 1]
        pick_loss = F.cross_entropy(pick_logits.flatten(1).float(), pick_target)
        place_loss = F.cross_entropy(place_logits.flatten(1).float(), place_target)
        loss = pick_loss + place_loss
        info = {"loss": loss.item(), "pick_loss": pick_loss.item(), "place_loss": place_loss.item()}
        return loss, info

    def train_step(self, batch: dict[str, Any], optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """One optimiser step on `batch`; returns the loss terms."""
        self.train()
        optimizer.zero_grad(set_to_none=True)
        loss, info = self.compute_loss(batch)
        loss.backward()
        optimizer.step()
        return info

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray], instruction: str | None = None) -> dict[str, Any]:
        """Pick and place poses for one observation (``color`` (H, W, 3) uint8, ``height`` (H, W)).

        Returns pose0 / pose1 as ((x, y, z), quat xyzw) — pose0 with yaw 0, pose1 with the decoded
        relative yaw — pick_pix and place_pix (u, v), place_rot (radians, in [0, 2*pi)), and the
        softmax heatmaps pick_heatmap (H, W) and place_heatmap (H, W) (max over rotations).
        """
        self.eval()
        device = self.device
        height = np.asarray(obs["height"], dtype=np.float32)
        x = raw_input(obs["color"], height).to(device)
        sentence = self.sentence_features(None if instruction is None else [instruction])
        h, w = height.shape

        pick_prob = F.softmax(self.pick(x, sentence).flatten(1).float(), dim=1).reshape(h, w)
        pick_index = int(torch.argmax(pick_prob))
        pick_pix = (pick_index // w, pick_index % w)

        pick_tensor = torch.tensor([pick_pix], device=device)
        place_logits = self.place(x, pick_tensor, sentence)[0]
        n_rot = place_logits.shape[0]
        place_prob = F.softmax(place_logits.flatten().float(), dim=0).reshape(n_rot, h, w)
        place_index = int(torch.argmax(place_prob))
        rot_bin, rest = divmod(place_index, h * w)
        place_pix = (rest // w, rest % w)
        place_rot = rot_bin * 2 * math.pi / n_rot

        return {
            "pose0": (pix_to_xyz(pick_pix, height), yaw_to_quat(0.0)),
            "pose1": (pix_to_xyz(place_pix, height), yaw_to_quat(place_rot)),
            "pick_pix": pick_pix,
            "place_pix": place_pix,
            "place_rot": place_rot,
            "pick_heatmap": pick_prob.cpu().numpy().astype(np.float32),
            "place_heatmap": place_prob.amax(dim=0).cpu().numpy().astype(np.float32),
        }

    def _frozen_prefixes(self) -> list[str]:
        modules = self.named_modules(remove_duplicate=False)  # the shared CLIP sits under several names
        return [name + "." for name, module in modules if isinstance(module, FrozenCLIP)]

    def trainable_state_dict(self) -> dict[str, torch.Tensor]:
        """The state dict without any frozen CLIP tensor."""
        prefixes = tuple(self._frozen_prefixes())
        return {k: v for k, v in self.state_dict().items() if not (prefixes and k.startswith(prefixes))}

    def load_trainable_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Load weights saved by :meth:`trainable_state_dict` (every trainable tensor must be present)."""
        missing, unexpected = self.load_state_dict(state, strict=False)
        prefixes = tuple(self._frozen_prefixes())
        missing = [k for k in missing if not (prefixes and k.startswith(prefixes))]
        if missing or unexpected:
            raise KeyError(f"checkpoint mismatch: missing {missing}, unexpected {unexpected}")

    def clip_source(self) -> str | None:
        return None if self.clip is None else self.clip.source

    def checkpoint_payload(self) -> dict[str, Any]:
        """What a checkpoint holds: agent name, config, CLIP weight source and trainable weights (CPU)."""
        return {
            "format": CHECKPOINT_FORMAT,
            "agent": self.name,
            "config": self.config.to_dict(),
            "clip_weights": self.clip_source(),
            "state_dict": {k: v.detach().cpu() for k, v in self.trainable_state_dict().items()},
        }

    def save_checkpoint(self, path: str | os.PathLike[str]) -> None:
        """Write agent name, config, CLIP weight source and trainable weights, atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = self.checkpoint_payload()
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                torch.save(payload, f)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
