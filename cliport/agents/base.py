"""Pick-and-place agent shared by both architectures: loss, training step, acting and checkpoints."""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cliport import __version__
from cliport.agents.config import AgentConfig
from cliport.env.heightmap import BOUNDS, PIXEL_SIZE, pix_to_xyz
from cliport.env.transforms import yaw_to_quat
from cliport.models.cuda_graphs import GraphedForward, GraphMemory
from cliport.models.encoders import EncoderNet, FrozenEncoder
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.preprocess import raw_input
from cliport.utils.device import bf16_native
from cliport.utils.files import save_safetensors, save_torch, write_json

#: 2 since the networks compute the reference CLIPort's functions (cliport 0.2.0); 1 before.
CHECKPOINT_FORMAT = 2
#: What ``save_pretrained`` writes into a folder: the trainable weights and a description of the agent.
PRETRAINED_WEIGHTS = "model.safetensors"
PRETRAINED_CONFIG = "config.json"
DEVICE_OPTIONS = ("channels_last", "bf16_clip", "fused_adam", "act_graphs")
LossFn = Callable[[dict[str, Any]], tuple[torch.Tensor, dict[str, float]]]


def optimizer_step(
    loss_fn: LossFn,
    batch: dict[str, Any],
    optimizer: torch.optim.Optimizer,
    autocast: contextlib.AbstractContextManager[Any] | None = None,
) -> dict[str, float]:
    """The one training step of the project: zero grads, loss (under ``autocast``), backward, step.

    ``loss_fn`` is an agent's ``compute_loss`` or a DDP-wrapped module with the same call signature.
    """
    optimizer.zero_grad(set_to_none=True)
    with autocast or contextlib.nullcontext():
        loss, info = loss_fn(batch)
    loss.backward()
    optimizer.step()
    return info


def weights_metadata(payload: dict[str, Any], step: int | None = None) -> dict[str, str]:
    """The string metadata of a safetensors weights file: a checkpoint payload's (see
    :meth:`PickPlaceAgent.checkpoint_payload`) agent, config and weight sources (JSON), its format and version,
    and the training step when known."""
    metadata = {
        "format": str(payload["format"]),
        "cliport_version": str(payload.get("cliport_version", "")),
        "agent": payload["agent"],
        "config": json.dumps(payload["config"]),
        "clip_weights": json.dumps(payload.get("clip_weights")),
        "weight_sources": json.dumps(payload.get("weight_sources", {})),
    }
    if step is not None:
        metadata["step"] = str(int(step))
    return metadata


def save_weights(payload: dict[str, Any], path: str | os.PathLike[str], step: int | None = None) -> None:
    """Write a checkpoint payload's trainable weights as a safetensors file (no pickle), its agent, config and
    weight sources in the file's metadata, atomically. ``cliport.agents.read_weights`` reads it back."""
    save_safetensors(payload["state_dict"], path, weights_metadata(payload, step))


class PickPlaceAgent(nn.Module):
    """Pick head + place head over a top-down (H, W) RGB-D observation.

    Training batch: ``color`` uint8 (B, H, W, 3), ``height`` float (B, H, W), ``pose0``/``pose1`` (B, 7)
    action poses (or ``pick_pix``/``place_pix`` (B, 2) and ``place_rot`` (B,) targets), ``lang`` list[str].
    """

    #: Set by ``@register_agent``: the registered name and config class.
    name: ClassVar[str] = ""
    config_class: ClassVar[type[AgentConfig]] = AgentConfig
    #: Whether the instruction changes what the agent does.
    uses_language: ClassVar[bool] = False
    #: Config fields naming pretrained weights (recorded in checkpoints, never saved in them).
    weight_sources: ClassVar[tuple[str, ...]] = ()
    #: Published columns of this agent: ``{table key in published_results.json: column}``.
    published_columns: ClassVar[dict[str, str]] = {}

    def __init__(
        self,
        config: AgentConfig,
        pick: PickHead,
        place: PlaceHead,
        encoder: FrozenEncoder | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.pick = pick
        self.place = place
        self.encoder = encoder
        # Per-device speed settings, see optimize_for_device(); each applies on CUDA only.
        self.device_options = dict.fromkeys(DEVICE_OPTIONS, True)
        # One memory pool and one lock for both forwards' graphs; they hold this agent weakly.
        self._graph_memory = GraphMemory()
        self._pick_graphs = GraphedForward(self._pick_forward, self._graph_memory)
        self._place_graphs = GraphedForward(self._place_forward, self._graph_memory)

    @property
    def device(self) -> torch.device:
        return next(self.pick.parameters()).device

    def optimize_for_device(
        self,
        channels_last: bool = True,
        bf16_clip: bool = True,
        fused_adam: bool = True,
        act_graphs: bool = True,
    ) -> PickPlaceAgent:
        """Choose the CUDA speed settings (all on by default); they follow the agent across ``.to()``.

        On CUDA: ``channels_last`` keeps the nets' weights and inputs (raw input, padded key input, query
        crops) in channels_last, so cuDNN never converts layouts; ``bf16_clip`` runs the frozen encoder's image
        trunk in bfloat16 (its features are returned as float32; the text encoder stays float32) on GPUs
        that compute bf16 natively (compute capability 8.0+; elsewhere it stays float32), and its float32
        weights come back when the setting is switched off or the agent leaves CUDA; ``fused_adam`` makes
        :meth:`make_optimizer` use the fused Adam kernel; ``act_graphs`` replays the pick and place
        forwards of :meth:`act_batch` as CUDA graphs (see :class:`~cliport.models.cuda_graphs.GraphedForward`:
        batches padded to 1, 2, 4 or 8, one memory pool). On the CPU all four are off whatever is asked:
        NCHW float32, foreach Adam, eager acting. :meth:`active_device_options` says which apply. Returns
        the agent.
        """
        self.device_options.update(
            channels_last=channels_last, bf16_clip=bf16_clip, fused_adam=fused_adam, act_graphs=act_graphs
        )
        self._apply_device_options()
        return self

    def set_act_graphs(self, enabled: bool) -> None:
        """Turn the CUDA-graph replay of act_batch's forwards on or off (CUDA only; eager elsewhere).
        Graphs captured so far are kept for when it is turned on again."""
        self.device_options["act_graphs"] = enabled

    def _use(self, option: str) -> bool:
        if not (self.device_options[option] and self.device.type == "cuda"):
            return False
        return option != "bf16_clip" or bf16_native(self.device)

    def active_device_options(self) -> dict[str, bool]:
        """The speed settings in effect on the agent's device now (what was asked for, where it applies)."""
        return {option: self._use(option) for option in DEVICE_OPTIONS}

    def _apply_device_options(self) -> None:
        self._pick_graphs.clear()
        self._place_graphs.clear()
        self._graph_memory.reset()
        layout = torch.channels_last if self._use("channels_last") else torch.contiguous_format
        for head in (self.pick, self.place):
            head.to(memory_format=layout)
            head.input_memory_format = layout
        if self.encoder is not None:
            self.encoder.set_image_dtype(torch.bfloat16 if self._use("bf16_clip") else torch.float32)

    def _apply(self, fn, recurse: bool = True):  # type: ignore[no-untyped-def]
        # Every .to() / .cuda() / .float() re-allocates the parameters: recapture graphs, and bring the
        # layout and the frozen trunk's precision in line with the (possibly new) device.
        out = super()._apply(fn, recurse)
        if getattr(self, "device_options", None) is not None:
            self._apply_device_options()
        return out

    def sentence_features(self, lang: list[str] | None) -> torch.Tensor | None:
        """(B,) instructions -> (B, sentence_dim) frozen-encoder sentence features (cached per string),
        or None for agents that do not read language."""
        if not self.uses_language:
            return None
        if lang is None or any(text is None for text in lang):
            raise ValueError(f"the {self.name} agent needs an instruction for every observation")
        assert self.encoder is not None
        return self.encoder.sentence_features(list(lang))

    def make_optimizer(self, eps: float = 1e-8) -> torch.optim.Optimizer:
        """Adam over the trainable parameters at the configured learning rate with epsilon ``eps`` (a training
        recipe's): the fused kernel on CUDA (see :meth:`optimize_for_device`), the foreach one elsewhere.
        Adam is per parameter, so one optimiser over every net steps as the reference's one per net does."""
        kernel = {"fused": True} if self._use("fused_adam") else {"foreach": True}
        return torch.optim.Adam(self.trainable_parameters(), lr=self.config.lr, eps=eps, **kernel)

    def set_encoder_norm_training(self, enabled: bool) -> int:
        """Whether training forwards run the frozen encoder's batch norms in training mode (each sample's own
        statistics; running statistics updated as the reference's batch-1 steps would), as the reference
        CLIPort's ``attention.train()`` does. Only nets that keep their own statistics (``per_net_clip_stats``)
        can: the shared encoder's are never saved. Acting is unaffected. Returns how many nets it applies to."""
        return sum(net.set_encoder_norm_training(enabled) for net in self.modules() if isinstance(net, EncoderNet))

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def logits(
        self, x: torch.Tensor, pick_pix: torch.Tensor, lang: list[str] | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Raw input (B, 6, H, W), pick pixels (B, 2) -> pick logits (B, H, W), place logits (B, R, H, W)."""
        sentence = self.sentence_features(lang)
        return self.pick(x, sentence), self.place(x, pick_pix, sentence)

    def action_targets(
        self, pose0: torch.Tensor | np.ndarray, pose1: torch.Tensor | np.ndarray, hw: tuple[int, int]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Training targets of pick and place poses (B, 7) (xyz + quaternion xyzw, world frame of the image):
        pick pixel (B, 2), place pixel (B, 2) (row, col; int64, clamped to the (H, W) image) and the
        rotation bin (B,) of the relative yaw, as the place head decodes it."""
        pose0 = torch.as_tensor(pose0, dtype=torch.float64)
        pose1 = torch.as_tensor(pose1, dtype=torch.float64)

        def pixels(pose: torch.Tensor) -> torch.Tensor:
            u = torch.round((pose[:, 1] - BOUNDS[1, 0]) / PIXEL_SIZE).clamp(0, hw[0] - 1)
            v = torch.round((pose[:, 0] - BOUNDS[0, 0]) / PIXEL_SIZE).clamp(0, hw[1] - 1)
            return torch.stack([u, v], dim=1).long()

        def yaw(pose: torch.Tensor) -> torch.Tensor:  # quat_to_yaw: the reference's labels' z angle
            x, y, z, w = pose[:, 3], pose[:, 4], pose[:, 5], pose[:, 6]
            return torch.atan2(2 * (x * y + w * z), 1 - 2 * (x * x + z * z))

        return pixels(pose0), pixels(pose1), self.place.rotation_bin(yaw(pose1) - yaw(pose0))

    def compute_loss(self, batch: dict[str, Any], loss: str = "sample_ce") -> tuple[torch.Tensor, dict[str, float]]:
        """Cross-entropy over all pick pixels plus over all place pixels x rotations, averaged over the batch.

        ``loss``: ``sample_ce``, each map's cross-entropy (Ravens'); ``cell_mean``, each map's cross-entropy
        divided by its cells, H * W for pick and R * H * W for place (the reference CLIPort's mean of
        ``-label * log_softmax`` over the map). The info dict always reports the per-sample cross-entropies
        (``pick_loss``, ``place_loss``, ``loss``), so that recipes compare on one scale.

        The targets come from the poses ``pose0``/``pose1`` (B, 7) (see :meth:`action_targets`), or are
        given directly as ``pick_pix``/``place_pix`` (B, 2) and ``place_rot`` (B,). The inputs are copied
        to the agent's device with ``non_blocking=True`` (asynchronous from pinned memory) before the raw
        input is built there, so only uint8 colours travel.
        """
        device = self.device

        def move(value: Any) -> torch.Tensor:
            return torch.as_tensor(value).to(device, non_blocking=True)

        x = raw_input(move(batch["color"]), move(batch["height"]))
        if "pose0" in batch:
            targets = self.action_targets(batch["pose0"], batch["pose1"], x.shape[-2:])
        else:
            targets = (batch["pick_pix"], batch["place_pix"], batch["place_rot"])
        pick_pix, place_pix, place_rot = (move(t).long() for t in targets)
        pick_logits, place_logits = self.logits(x, pick_pix, batch.get("lang"))
        h, w = x.shape[-2:]
        pick_target = pick_pix[:, 0] * w + pick_pix[:, 1]
        place_target = (place_rot * h + place_pix[:, 0]) * w + place_pix[:, 1]
        pick_loss = F.cross_entropy(pick_logits.flatten(1).float(), pick_target)
        place_loss = F.cross_entropy(place_logits.flatten(1).float(), place_target)
        total = pick_loss + place_loss
        info = {"loss": total.item(), "pick_loss": pick_loss.item(), "place_loss": place_loss.item()}
        if loss == "cell_mean":
            total = pick_loss / pick_logits[0].numel() + place_loss / place_logits[0].numel()
        elif loss != "sample_ce":
            raise ValueError(f"unknown loss {loss!r}; choose cell_mean or sample_ce")
        return total, info

    def train_step(
        self,
        batch: dict[str, Any],
        optimizer: torch.optim.Optimizer,
        autocast: contextlib.AbstractContextManager[Any] | None = None,
        loss: str = "sample_ce",
    ) -> dict[str, float]:
        """One optimiser step on `batch` with the ``loss`` of :meth:`compute_loss` (see :func:`optimizer_step`);
        returns the loss terms."""
        self.train()
        return optimizer_step(lambda b: self.compute_loss(b, loss), batch, optimizer, autocast)

    def act(self, obs: dict[str, np.ndarray], instruction: str | None = None) -> dict[str, Any]:
        """Pick and place poses for one observation (``color`` (H, W, 3) uint8, ``height`` (H, W)).

        Returns pose0 / pose1 as ((x, y, z), quat xyzw) — pose0 with yaw 0, pose1 with the decoded
        relative yaw — pick_pix and place_pix (u, v), place_bin (the rotation bin k) and its yaw place_rot
        (radians, in [0, 2*pi); see :meth:`PlaceHead.bin_yaw`), and the
        softmax heatmaps pick_heatmap (H, W) and place_heatmap (H, W) (max over rotations).
        Same as ``act_batch([obs], [instruction])[0]``.
        """
        return self.act_batch([obs], [instruction])[0]

    def _pick_forward(self, x: torch.Tensor, sentence: torch.Tensor | None) -> torch.Tensor:
        """Raw (B, 6, H, W), sentence (B, sentence_dim) or None -> pick logits (B, H, W)."""
        return self.pick(x, sentence)

    def _place_forward(self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None) -> torch.Tensor:
        """Raw (B, 6, H, W), pick (B, 2) int64, sentence (B, sentence_dim) or None -> place logits (B, R, H, W)."""
        return self.place(x, pick_pix, sentence)

    def _graphs_apply(self, x: torch.Tensor) -> bool:
        return self._use("act_graphs") and not torch.is_autocast_enabled(x.device.type)

    def _act_sentence(self, instructions: list[str | None]) -> torch.Tensor | None:
        if all(i is None for i in instructions):
            return self.sentence_features(None)
        return self.sentence_features(list(instructions))  # type: ignore[arg-type]

    @torch.no_grad()
    def act_batch(
        self, observations: list[dict[str, np.ndarray]], instructions: list[str | None]
    ) -> list[dict[str, Any]]:
        """:meth:`act` for B observations of one image size at once: one batched pick forward, then one
        batched place forward over the (observation, chosen pick) pairs.

        observations: B dicts of ``color`` (H, W, 3) uint8 and ``height`` (H, W); instructions: B strings
        (or None for agents without language). Returns B dicts as :meth:`act` does. On CUDA the two
        forwards replay CUDA graphs (see :meth:`optimize_for_device`) unless autocast is active.
        """
        if len(observations) != len(instructions):
            raise ValueError(f"{len(observations)} observations but {len(instructions)} instructions")
        if not observations:
            return []
        self.eval()
        device = self.device
        heights = [np.asarray(obs["height"], dtype=np.float32) for obs in observations]
        if len({h.shape for h in heights}) != 1:
            raise ValueError(f"act_batch needs observations of one size, got {sorted({h.shape for h in heights})}")
        color = torch.from_numpy(np.stack([np.asarray(obs["color"]) for obs in observations]))
        x = raw_input(color.to(device), torch.from_numpy(np.stack(heights)).to(device))
        sentence = self._act_sentence(instructions)
        b, h, w = len(observations), *heights[0].shape
        graphs = self._graphs_apply(x)

        pick_forward = self._pick_graphs if graphs else self._pick_forward
        pick_logits = pick_forward(x, sentence)
        pick_prob = F.softmax(pick_logits.reshape(b, h * w).float(), dim=1)
        pick_index = torch.argmax(pick_prob, dim=1)
        pick_pix = torch.stack([pick_index // w, pick_index % w], dim=1)

        place_forward = self._place_graphs if graphs else self._place_forward
        place_logits = place_forward(x, pick_pix, sentence)
        n_rot = place_logits.shape[1]
        place_prob = F.softmax(place_logits.reshape(b, n_rot * h * w).float(), dim=1)
        place_index = torch.argmax(place_prob, dim=1)
        place_heatmap = place_prob.reshape(b, n_rot, h, w).amax(dim=1)

        pick_pix_np = pick_pix.cpu().numpy()
        place_index_np = place_index.cpu().numpy()
        pick_heatmaps = pick_prob.reshape(b, h, w).cpu().numpy().astype(np.float32)
        place_heatmaps = place_heatmap.cpu().numpy().astype(np.float32)
        results = []
        for i in range(b):
            pick = (int(pick_pix_np[i, 0]), int(pick_pix_np[i, 1]))
            rot_bin, rest = divmod(int(place_index_np[i]), h * w)
            place = (rest // w, rest % w)
            place_yaw = self.place.bin_yaw(rot_bin)
            results.append(
                {
                    "pose0": (pix_to_xyz(pick, heights[i]), yaw_to_quat(0.0)),
                    "pose1": (pix_to_xyz(place, heights[i]), yaw_to_quat(place_yaw)),
                    "pick_pix": pick,
                    "place_pix": place,
                    "place_rot": place_yaw % (2 * math.pi),
                    "place_bin": rot_bin,
                    "pick_heatmap": pick_heatmaps[i],
                    "place_heatmap": place_heatmaps[i],
                }
            )
        return results

    def _frozen_prefixes(self) -> list[str]:
        modules = self.named_modules(remove_duplicate=False)  # the shared encoder sits under several names
        return [name + "." for name, module in modules if isinstance(module, FrozenEncoder)]

    def trainable_state_dict(self) -> dict[str, torch.Tensor]:
        """The state dict without any frozen encoder tensor."""
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
        """Where the frozen CLIP's weights came from, or None for agents without CLIP."""
        return None if self.encoder is None else self.encoder.sources().get("clip_weights")

    def weight_source_values(self) -> dict[str, str]:
        """``{config field: source}`` of every pretrained part (e.g. ``{"clip_weights": "openai"}``)."""
        return {field: getattr(self.config, field) for field in self.weight_sources}

    def describe(self) -> dict[str, Any]:
        """What every result of this agent records about it: name, pretrained weight sources and rotation count."""
        return {
            "agent": self.name,
            "clip_weights": self.clip_source(),
            "weight_sources": self.weight_source_values(),
            "n_rotations": self.config.n_rotations,
        }

    def checkpoint_payload(self) -> dict[str, Any]:
        """What a checkpoint holds: agent name, config, pretrained weight sources and trainable weights (CPU)."""
        return {
            "format": CHECKPOINT_FORMAT,
            "cliport_version": __version__,
            "agent": self.name,
            "config": self.config.to_dict(),
            "clip_weights": self.clip_source(),
            "weight_sources": self.weight_source_values(),
            "state_dict": {k: v.detach().cpu() for k, v in self.trainable_state_dict().items()},
        }

    def save_checkpoint(self, path: str | os.PathLike[str]) -> None:
        """Write agent name, config, weight sources and trainable weights, atomically."""
        save_torch(self.checkpoint_payload(), path)

    def save_pretrained(self, folder: str | os.PathLike[str]) -> str:
        """Write ``folder/model.safetensors`` (the trainable weights; agent, config and weight sources in its
        metadata, no pickle) and ``folder/config.json`` (the same description as JSON); returns the folder.
        Frozen pretrained parts are not written: they are reloaded from the recorded sources.
        :meth:`from_pretrained` loads the folder. A training run's folder is refused (its config.json is the
        run's; its ``model.safetensors`` is written by training)."""
        from cliport.errors import RunDirError

        config_path = os.path.join(folder, PRETRAINED_CONFIG)
        if os.path.isfile(config_path):
            with open(config_path) as f:
                existing = json.load(f)
            if isinstance(existing, dict) and "task" in existing:
                raise RunDirError(f"{folder} holds a training run: save_pretrained into another folder")
        payload = self.checkpoint_payload()
        save_weights(payload, os.path.join(folder, PRETRAINED_WEIGHTS))
        description = {k: payload[k] for k in ("agent", "config", "clip_weights", "weight_sources")}
        write_json(config_path, {**description, "format": CHECKPOINT_FORMAT, "cliport_version": __version__})
        return str(folder)

    @classmethod
    def from_pretrained(
        cls,
        source: str | os.PathLike[str],
        checkpoint: str | int | None = None,
        device: str | torch.device = "cpu",
        weights: dict[str, str] | None = None,
    ) -> PickPlaceAgent:
        """An agent from a run folder, ``hf://org/name[@revision]``, a :meth:`save_pretrained` folder or a
        weights file (``.safetensors``, or a ``.pt`` checkpoint).

        In a folder, ``checkpoint`` None reads ``model.safetensors`` (in a run: the newest scheduled
        checkpoint; in a pushed repo: the pushed one); runs written before safetensors existed give their newest
        scheduled ``.pt`` checkpoint instead. ``checkpoint`` "best" (by val.json), "last" or a step picks a
        checkpoint of a run (its ``.safetensors`` where present, else its ``.pt``). Safetensors are read without
        pickle; ``.pt`` files with torch's weights-only loader. Pretrained parts are reloaded from the recorded
        sources unless ``weights`` maps a source field to another (as :func:`cliport.agents.load_agent`).
        Called on an agent class (``TwoStreamAgent.from_pretrained``), the weights must be of that agent.
        """
        from cliport.agents import agent_class, agent_from_payload, read_checkpoint, read_weights
        from cliport.errors import CheckpointError

        path = pretrained_file(str(source), checkpoint)
        payload = read_weights(path) if path.endswith(".safetensors") else read_checkpoint(path)
        if not issubclass(agent_class(payload["agent"]), cls):  # before any pretrained part is loaded
            raise CheckpointError(f"{path} holds a {payload['agent']} agent, not a {cls.name or cls.__name__} one")
        return agent_from_payload(payload, path, device=device, weights=weights)


def pretrained_file(source: str, checkpoint: str | int | None = None) -> str:
    """The weights file :meth:`PickPlaceAgent.from_pretrained` reads for ``source`` and ``checkpoint``;
    RunDirError / ConfigError naming the problem."""
    from cliport.errors import ConfigError, RunDirError
    from cliport.utils.run_dir import LAST, RunDir

    if source.startswith("hf://"):
        # Hub runs are fetched by the deployment layer's resolver (the Hugging Face cache, offline aware).
        from cliport.deploy.hub import resolve_run_dir

        source = resolve_run_dir(source)
    if os.path.isfile(source):
        if checkpoint is not None:
            raise ConfigError(f"checkpoint={checkpoint!r} needs a run folder, not the file {source}")
        return source
    if not os.path.isdir(source):
        raise RunDirError(f"no run folder or weights file at {source}")
    run = RunDir(source)
    if checkpoint is None:
        if os.path.isfile(run.model_weights):
            return run.model_weights
        steps = run.checkpoint_steps()  # a run from before safetensors weights: its newest scheduled checkpoint
        if not steps:
            raise RunDirError(f"{source} holds no {PRETRAINED_WEIGHTS} and no scheduled checkpoints")
        return run.checkpoint(steps[-1])
    (step,) = run.resolve(str(checkpoint), run.best_step() if checkpoint == "best" else None, allow_all=False)
    if step == LAST:
        return run.checkpoint(LAST)
    return run.weights(step) if os.path.isfile(run.weights(step)) else run.checkpoint(step)
