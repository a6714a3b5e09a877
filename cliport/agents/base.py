"""The pick-and-place agent every architecture shares, composed of its parts' modules: the objective and
optimiser step (:mod:`~cliport.agents.loss`), targets and actions between poses and maps
(:mod:`~cliport.agents.decode`), the per-device speed settings (:mod:`~cliport.agents.device_options`) and
the weights on disk (:mod:`~cliport.agents.checkpoint`)."""

from __future__ import annotations

import contextlib
import os
from typing import Any, ClassVar, TypedDict

import numpy as np
import torch
from torch import nn

from cliport import __version__
from cliport.agents.checkpoint import CHECKPOINT_FORMAT, pretrained_file, read_payload, save_pretrained_folder
from cliport.agents.config import AgentConfig
from cliport.agents.decode import action_targets, actions, decode_pick, decode_place
from cliport.agents.device_options import DEVICE_OPTIONS, apply_layout_and_precision, option_applies
from cliport.agents.loss import optimizer_step, pick_place_terms, pick_term, place_term, terms_info
from cliport.agents.registry import agent_class, agent_from_payload
from cliport.errors import CheckpointError, ConfigError
from cliport.models.cuda_graphs import GraphedForward, GraphMemory
from cliport.models.encoder_net import EncoderNet
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.preprocess import raw_input
from cliport.utils.files import save_torch


class TrainingInputs(TypedDict):
    """A training batch as :meth:`PickPlaceAgent.loss_terms` takes it (see :meth:`PickPlaceAgent.training_inputs`)."""

    color: torch.Tensor  # (B, H, W, 3) uint8
    height: torch.Tensor  # (B, H, W) float
    pick_pix: torch.Tensor  # (B, 2) int64
    place_pix: torch.Tensor  # (B, 2) int64
    place_rot: torch.Tensor  # (B,) int64
    sentence: torch.Tensor | None  # (B, sentence_dim), or None for agents without language


class PickPlaceAgent(nn.Module):
    """Pick head + place head over a top-down (H, W) RGB-D observation.

    Training batch: ``color`` uint8 (B, H, W, 3), ``height`` float (B, H, W), ``pose0``/``pose1`` (B, 7)
    action poses (or ``pick_pix``/``place_pix`` (B, 2) and ``place_rot`` (B,) targets), ``lang`` list[str].
    """

    #: Set by ``@register_agent``: the registered name and config class.
    name: ClassVar[str] = ""
    config_class: ClassVar[type[AgentConfig]] = AgentConfig
    #: Buffers of agents with ``center_sentences`` (see :meth:`fit_sentence_centering`).
    sentence_mean: torch.Tensor
    sentence_scale: torch.Tensor
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
        self.centers_sentences = bool(getattr(config, "center_sentences", False))
        if self.centers_sentences:
            if encoder is None:
                raise ConfigError(f"center_sentences needs an agent that reads instructions, not {type(self).__name__}")
            # Fitted by fit_sentence_centering (cliport-train does, once) and saved with the weights.
            self.register_buffer("sentence_mean", torch.zeros(encoder.sentence_dim))
            self.register_buffer("sentence_scale", torch.zeros(()))
        self._sentences_fitted = False  # read without a device sync (the buffers may live on a GPU)
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
        :meth:`make_optimizer` use the fused Adam kernel (on the CPU too); ``act_graphs`` replays the pick and place
        forwards of :meth:`act_batch` as CUDA graphs (see :class:`~cliport.models.cuda_graphs.GraphedForward`:
        batches padded to 1, 2, 4 or 8, one memory pool). On the CPU only fused Adam applies:
        NCHW float32, eager acting. :meth:`active_device_options` says which apply. Returns
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
        return option_applies(self.device_options, option, self.device)

    def active_device_options(self) -> dict[str, bool]:
        """The speed settings in effect on the agent's device now (what was asked for, where it applies)."""
        return {option: self._use(option) for option in DEVICE_OPTIONS}

    def _apply_device_options(self) -> None:
        self._pick_graphs.clear()
        self._place_graphs.clear()
        self._graph_memory.reset()
        heads = (self.pick, self.place)
        apply_layout_and_precision(heads, self.encoder, self._use("channels_last"), self._use("bf16_clip"))

    def _apply(self, fn, recurse: bool = True):  # type: ignore[no-untyped-def]  # torch's private hook, untyped
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
        features = self.encoder.sentence_features(list(lang))
        if not self.centers_sentences:
            return features
        if not self._sentences_fitted:
            raise RuntimeError(
                "this agent centres its sentence features but they were never fitted: call "
                "fit_sentence_centering(the training instructions) first (cliport-train does)"
            )
        return (features - self.sentence_mean) * self.sentence_scale

    def fit_sentence_centering(self, instructions: list[str]) -> dict[str, float]:
        """Fit the centring of ``center_sentences`` to ``instructions`` (the training set's): the mean of their
        distinct strings' features, and the scale that keeps their RMS norm. Returns what was fitted."""
        if not self.centers_sentences:
            raise ValueError(f"this {self.name} agent does not centre its sentence features (center_sentences is off)")
        assert self.encoder is not None
        texts = sorted({text for text in instructions if text})
        if len(texts) < 2:
            raise ValueError(f"centring sentence features needs at least two distinct instructions, got {texts}")
        with torch.no_grad():
            features = self.encoder.sentence_features(texts)
            mean = features.mean(0)
            spread = (features - mean).pow(2).sum(1).mean().sqrt()
            if not spread > 0:
                raise ValueError("the instructions' sentence features are all the same: nothing to centre")
            self.sentence_mean.copy_(mean)
            self.sentence_scale.copy_(features.pow(2).sum(1).mean().sqrt() / spread)
        self._sentences_fitted = True
        return {"instructions": len(texts), "scale": float(self.sentence_scale)}

    def make_optimizer(self, eps: float = 1e-8) -> torch.optim.Optimizer:
        """Adam over the trainable parameters at the configured learning rate with epsilon ``eps`` (a training
        recipe's): the fused kernel on CUDA and the CPU (see :meth:`optimize_for_device`), the foreach one elsewhere
        or when it is switched off.
        Adam is per parameter, so one optimiser over every net steps as the reference's one per net does."""
        fused = self._use("fused_adam")
        return torch.optim.Adam(
            self.trainable_parameters(),
            lr=self.config.lr,
            eps=eps,
            fused=fused or None,
            foreach=None if fused else True,
        )

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
        rotation bin (B,) of the relative yaw, as the place head decodes it (see
        :func:`~cliport.agents.decode.action_targets`)."""
        return action_targets(pose0, pose1, hw, self.place.n_rotations)

    def training_inputs(self, batch: dict[str, Any], device: torch.device | None = None) -> TrainingInputs:
        """A training batch as the tensors :meth:`loss_terms` takes, on ``device`` (default: the agent's):
        ``color`` (B, H, W, 3) uint8, ``height`` (B, H, W), ``pick_pix``/``place_pix`` (B, 2) and ``place_rot``
        (B,) int64, and ``sentence`` (B, sentence_dim) or None (always on the agent's device). With ``device`` the
        CPU, tensors the batch holds on the CPU (pinned or not) are returned as they are.

        The targets come from the poses ``pose0``/``pose1`` (B, 7) (see :meth:`action_targets`), or are
        given directly as ``pick_pix``/``place_pix`` (B, 2) and ``place_rot`` (B,). The inputs are copied
        to the agent's device with ``non_blocking=True`` (asynchronous from pinned memory), so only uint8
        colours travel; the sentence features are the frozen encoder's (cached per instruction).
        """
        device = self.device if device is None else device

        def move(value: Any) -> torch.Tensor:
            return torch.as_tensor(value).to(device, non_blocking=True)

        color, height = move(batch["color"]), move(batch["height"])
        if "pose0" in batch:
            targets = self.action_targets(batch["pose0"], batch["pose1"], (height.shape[-2], height.shape[-1]))
        else:
            targets = (batch["pick_pix"], batch["place_pix"], batch["place_rot"])
        pick_pix, place_pix, place_rot = (move(t).long() for t in targets)
        return {
            "color": color,
            "height": height,
            "pick_pix": pick_pix,
            "place_pix": place_pix,
            "place_rot": place_rot,
            "sentence": self.sentence_features(batch.get("lang")),
        }

    def loss_terms(
        self,
        color: torch.Tensor,
        height: torch.Tensor,
        pick_pix: torch.Tensor,
        place_pix: torch.Tensor,
        place_rot: torch.Tensor,
        sentence: torch.Tensor | None,
        loss: str = "sample_ce",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The training objective as a function of tensors on the agent's device (:meth:`training_inputs`): colour
        (B, H, W, 3) uint8, height (B, H, W), target pixels (B, 2) and rotation bins (B,) int64, sentence features
        (B, sentence_dim) or None -> the loss to minimise and the per-sample cross-entropies (3,) (``loss``,
        ``pick_loss``, ``place_loss``; see :func:`~cliport.agents.loss.pick_place_terms`). It reads nothing
        back to the host: a training step built on it can be captured as one CUDA graph."""
        x = raw_input(color, height)
        pick_logits, place_logits = self.pick(x, sentence), self.place(x, pick_pix, sentence)
        return pick_place_terms(pick_logits, place_logits, pick_pix, place_pix, place_rot, loss)

    def pick_loss_terms(
        self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None, loss: str = "sample_ce"
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The pick half of :meth:`loss_terms`: raw input (B, 6, H, W) (:func:`~cliport.models.preprocess.raw_input`),
        target pixels (B, 2) int64, sentence features -> the pick's share of the loss to minimise and its per-sample
        cross-entropy (scalars, :func:`~cliport.agents.loss.pick_term`). No parameter is shared with the place
        half, so the two can be differentiated separately, even at once (see
        :class:`~cliport.train.graphed_step.TrainStep`)."""
        return pick_term(self.pick(x, sentence), pick_pix, loss)

    def place_loss_terms(
        self,
        x: torch.Tensor,
        pick_pix: torch.Tensor,
        place_pix: torch.Tensor,
        place_rot: torch.Tensor,
        sentence: torch.Tensor | None,
        loss: str = "sample_ce",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The place half of :meth:`loss_terms`: raw input (B, 6, H, W), pick and place target pixels (B, 2) and
        rotation bins (B,) int64, sentence features -> the place's share of the loss to minimise and its per-sample
        cross-entropy (scalars, :func:`~cliport.agents.loss.place_term`)."""
        return place_term(self.place(x, pick_pix, sentence), place_pix, place_rot, loss)

    def compute_loss(self, batch: dict[str, Any], loss: str = "sample_ce") -> tuple[torch.Tensor, dict[str, float]]:
        """Cross-entropy over all pick pixels plus over all place pixels x rotations, averaged over the batch.

        ``loss``: ``sample_ce``, each map's cross-entropy (Ravens'); ``cell_mean``, each map's cross-entropy
        divided by its cells, H * W for pick and R * H * W for place (the reference CLIPort's mean of
        ``-label * log_softmax`` over the map). The info dict always reports the per-sample cross-entropies
        (``pick_loss``, ``place_loss``, ``loss``), so that recipes compare on one scale. The batch is read as
        :meth:`training_inputs` says (poses or targets; copied to the device) and the loss is
        :meth:`loss_terms`'.
        """
        total, terms = self.loss_terms(**self.training_inputs(batch), loss=loss)
        return total, terms_info(terms)

    def train_step(
        self,
        batch: dict[str, Any],
        optimizer: torch.optim.Optimizer,
        autocast: contextlib.AbstractContextManager[Any] | None = None,
        loss: str = "sample_ce",
    ) -> dict[str, float]:
        """One optimiser step on `batch` with the ``loss`` of :meth:`compute_loss` (see
        :func:`~cliport.agents.loss.optimizer_step`); returns the loss terms."""
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
        texts = [i for i in instructions if i is not None]
        if len(texts) != len(instructions):
            raise ValueError("an act batch mixes instructions with None: give every observation one, or none")
        return self.sentence_features(texts)

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
        graphs = self._graphs_apply(x)
        pick_prob, pick_pix = decode_pick((self._pick_graphs if graphs else self._pick_forward)(x, sentence))
        place_logits = (self._place_graphs if graphs else self._place_forward)(x, pick_pix, sentence)
        place_index, place_heatmap = decode_place(place_logits)
        return actions(pick_pix, pick_prob, place_index, place_heatmap, heights, self.place.bin_yaw)

    def _frozen_prefixes(self) -> list[str]:
        modules = self.named_modules(remove_duplicate=False)  # the shared encoder sits under several names
        return [name + "." for name, module in modules if isinstance(module, FrozenEncoder)]

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):  # type: ignore[no-untyped-def]  # torch's hook
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        if self.centers_sentences:
            self._sentences_fitted = bool(self.sentence_scale > 0)

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
        return save_pretrained_folder(self.checkpoint_payload(), folder)

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
        path = pretrained_file(str(source), checkpoint)
        payload = read_payload(path)
        if not issubclass(agent_class(payload["agent"]), cls):  # before any pretrained part is loaded
            raise CheckpointError(f"{path} holds a {payload['agent']} agent, not a {cls.name or cls.__name__} one")
        return agent_from_payload(payload, path, device=device, weights=weights)
