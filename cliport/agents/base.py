"""The pick-and-place agent every architecture shares: its nets (a pick head, a place head, an optional frozen
encoder) and its public face, each job handed to the part named for it: the per-device speed settings
(:mod:`~cliport.agents.device_options`), the sentence features and their centring
(:mod:`~cliport.agents.sentences`), the training inputs, objective and optimiser (:mod:`~cliport.agents.loss`),
acting: targets and actions between poses and maps (:mod:`~cliport.agents.decode`), and the weights on disk
(:mod:`~cliport.agents.checkpoint`)."""

from __future__ import annotations

import os
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from cliport import __version__
from cliport.agents import checkpoint as ckpt
from cliport.agents import decode, sentences
from cliport.agents import loss as objective
from cliport.agents.config import AgentConfig
from cliport.agents.device_options import DEVICE_OPTIONS, apply_layout_and_precision, option_applies
from cliport.agents.loss import TrainingInputs
from cliport.agents.registry import agent_class, make_agent
from cliport.errors import CheckpointError, ConfigError
from cliport.models.cuda_graphs import GraphedForward, GraphMemory
from cliport.models.encoder_net import EncoderNet
from cliport.models.encoders.base import FrozenEncoder
from cliport.models.encoders.dense_clip import PhraseBank
from cliport.models.heads import PickHead, PlaceHead
from cliport.models.preprocess import raw_input
from cliport.utils.files import save_torch


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
    #: The texts similarity maps compete with (two_stream with ``similarity_bank``), fitted when training starts.
    phrase_bank: PhraseBank | None
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
        self.phrase_bank = None
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
        """The device the agent's nets are on."""
        return next(self.pick.parameters()).device

    def optimize_for_device(
        self,
        channels_last: bool = True,
        bf16_clip: bool = True,
        fused_adam: bool = True,
        act_graphs: bool = True,
    ) -> PickPlaceAgent:
        """Choose the speed settings (all on by default; :mod:`~cliport.agents.device_options` says what each
        does); they follow the agent across ``.to()``. Each applies on CUDA only, but ``fused_adam``, which applies
        on the CPU too; :meth:`active_device_options` says which apply. The float32 weights of ``bf16_clip``'s
        trunk come back when it is switched off or the agent leaves CUDA. Returns the agent."""
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
        """(B,) instructions -> (B, sentence_dim) frozen-encoder sentence features (cached per string), or None
        for agents that do not read language; with ``similarity_maps``, (B, (1 + SIMILARITY_MAPS) * sentence_dim):
        the text embeddings of :func:`~cliport.agents.sentences.similarity_texts` after them."""
        if not self.uses_language:
            return None
        assert self.encoder is not None
        texts = sentences.check_instructions(self.name, lang)
        if self.phrase_bank is not None and not self.phrase_bank.fitted:
            raise RuntimeError(
                "this agent's similarity maps compete with a phrase bank that was never fitted: call "
                "agent.phrase_bank.fit(agent.encoder, the training instructions) first (cliport-train does)"
            )
        rate = getattr(self.config, "gate_phrase_dropout", 0.0)
        gated = sentences.gate_texts(self.encoder, texts, rate, self.phrase_bank, self.training)
        features = self.encoder.sentence_features(gated)
        if self.centers_sentences:
            features = sentences.centred(features, self.sentence_mean, self.sentence_scale, self._sentences_fitted)
        if getattr(self.config, "similarity_maps", False):
            features = torch.cat([features, sentences.similarity_texts(self.encoder, texts)], dim=1)
        return features

    def fit_sentence_centering(self, instructions: list[str]) -> dict[str, float]:
        """Fit the centring of ``center_sentences`` to ``instructions`` (the training set's): the mean of their
        distinct strings' features, and the scale that keeps their RMS norm. Returns what was fitted."""
        if not self.centers_sentences:
            raise ValueError(f"this {self.name} agent does not centre its sentence features (center_sentences is off)")
        assert self.encoder is not None
        fitted = sentences.fit_centering(self.encoder, instructions, self.sentence_mean, self.sentence_scale)
        self._sentences_fitted = True
        return fitted

    def make_optimizer(self, eps: float = 1e-8) -> torch.optim.Optimizer:
        """Adam over the trainable parameters at the configured learning rate with epsilon ``eps`` (a training
        recipe's): fused on CUDA and the CPU unless ``fused_adam`` is off (:func:`~.loss.make_optimizer`)."""
        return objective.make_optimizer(self.trainable_parameters(), self.config.lr, eps, self._use("fused_adam"))

    def set_encoder_norm_training(self, enabled: bool) -> int:
        """Whether training forwards run the frozen encoder's batch norms in training mode, as the reference
        CLIPort's ``attention.train()`` does (:meth:`EncoderNet.set_encoder_norm_training`); only nets with their own
        statistics (``per_net_clip_stats``) can. Acting is unaffected. Returns how many nets it applies to."""
        return sum(net.set_encoder_norm_training(enabled) for net in self.modules() if isinstance(net, EncoderNet))

    def trainable_parameters(self) -> list[nn.Parameter]:
        """The parameters training updates (every one but the frozen encoders')."""
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
        return decode.action_targets(pose0, pose1, hw, self.place.n_rotations)

    def training_inputs(self, batch: dict[str, Any], device: torch.device | None = None) -> TrainingInputs:
        """A training batch as the tensors :meth:`_loss_terms` takes, on ``device`` (default: the agent's):
        ``color`` (B, H, W, 3) uint8, ``height`` (B, H, W), ``pick_pix``/``place_pix`` (B, 2) and ``place_rot``
        (B,) int64, and ``sentence`` (B, sentence_dim) or None (always on the agent's device). With ``device`` the
        CPU, tensors the batch holds on the CPU (pinned or not) are returned as they are. The targets come from the
        poses (:meth:`action_targets`) or the batch's own (:func:`~cliport.agents.loss.batch_tensors`)."""
        device = self.device if device is None else device
        color, height, pick_pix, place_pix, place_rot = objective.batch_tensors(batch, device, self.action_targets)
        return {
            "color": color,
            "height": height,
            "pick_pix": pick_pix,
            "place_pix": place_pix,
            "place_rot": place_rot,
            "sentence": self.sentence_features(batch.get("lang")),
        }

    def _loss_terms(
        self,
        color: torch.Tensor,
        height: torch.Tensor,
        pick_pix: torch.Tensor,
        place_pix: torch.Tensor,
        place_rot: torch.Tensor,
        sentence: torch.Tensor | None,
        loss: str = "sample_ce",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The training objective of tensors on the agent's device (:meth:`training_inputs`) -> the loss to minimise
        and the per-sample cross-entropies (3,) (:func:`~cliport.agents.loss.pick_place_terms`). It reads nothing
        back to the host: a training step built on it can be captured as one CUDA graph."""
        x = raw_input(color, height)
        pick_logits, place_logits = self.pick(x, sentence), self.place(x, pick_pix, sentence)
        return objective.pick_place_terms(pick_logits, place_logits, pick_pix, place_pix, place_rot, loss)

    def _pick_loss_terms(
        self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None, loss: str = "sample_ce"
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The pick half of :meth:`_loss_terms` on the raw input (B, 6, H, W) (:func:`~cliport.agents.loss.pick_term`).
        It shares no parameter with the place half: the two can be differentiated apart, even at once."""
        return objective.pick_term(self.pick(x, sentence), pick_pix, loss)

    def _place_loss_terms(
        self,
        x: torch.Tensor,
        pick_pix: torch.Tensor,
        place_pix: torch.Tensor,
        place_rot: torch.Tensor,
        sentence: torch.Tensor | None,
        loss: str = "sample_ce",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The place half of :meth:`_loss_terms` on the raw input (B, 6, H, W) (:func:`~.loss.place_term`)."""
        return objective.place_term(self.place(x, pick_pix, sentence), place_pix, place_rot, loss)

    def compute_loss(self, batch: dict[str, Any], loss: str = "sample_ce") -> tuple[torch.Tensor, dict[str, float]]:
        """The training objective of a batch as :meth:`training_inputs` reads it: the loss to minimise (``loss``:
        ``sample_ce`` or ``cell_mean``, :func:`~cliport.agents.loss.pick_place_terms`) and the per-sample
        cross-entropies (``loss``, ``pick_loss``, ``place_loss``) as floats, one scale for every recipe. One
        optimiser step on it: ``agent.train()``, then
        ``optimizer_step(agent.compute_loss, batch, optimizer)`` (:func:`~cliport.agents.loss.optimizer_step`)."""
        total, terms = self._loss_terms(**self.training_inputs(batch), loss=loss)
        return total, objective.terms_info(terms)

    def act(self, obs: dict[str, np.ndarray], instruction: str | None = None) -> dict[str, Any]:
        """Pick and place poses for one observation (``color`` (H, W, 3) uint8, ``height`` (H, W)).

        Returns pose0 / pose1 as ((x, y, z), quat xyzw) — pose0 with yaw 0, pose1 with the decoded relative yaw —
        pick_pix and place_pix (u, v), place_bin (the rotation bin k) and its yaw place_rot (radians, in [0, 2*pi);
        :meth:`PlaceHead.bin_yaw`), and the softmax heatmaps pick_heatmap (H, W) and place_heatmap (H, W) (max over
        rotations). Same as ``act_batch([obs], [instruction])[0]``."""
        return self.act_batch([obs], [instruction])[0]

    def _pick_forward(self, x: torch.Tensor, sentence: torch.Tensor | None) -> torch.Tensor:
        """Raw (B, 6, H, W), sentence (B, sentence_dim) or None -> pick logits (B, H, W)."""
        return self.pick(x, sentence)

    def _place_forward(self, x: torch.Tensor, pick_pix: torch.Tensor, sentence: torch.Tensor | None) -> torch.Tensor:
        """Raw (B, 6, H, W), pick (B, 2) int64, sentence (B, sentence_dim) or None -> place logits (B, R, H, W)."""
        return self.place(x, pick_pix, sentence)

    @torch.no_grad()
    def act_batch(
        self, observations: list[dict[str, np.ndarray]], instructions: list[str | None]
    ) -> list[dict[str, Any]]:
        """:meth:`act` for B observations of one image size (B strings, or None for agents without language) at
        once, B dicts as :meth:`act` returns: one batched forward per head (:func:`~cliport.agents.decode.decide`),
        replayed as CUDA graphs on CUDA unless autocast is active (:meth:`optimize_for_device`)."""
        if len(observations) != len(instructions):
            raise ValueError(f"{len(observations)} observations but {len(instructions)} instructions")
        if not observations:
            return []
        self.eval()
        x, heights = decode.act_input(observations, self.device)
        sentence = self.sentence_features(sentences.act_instructions(instructions))
        pick, place = self._act_forwards(x)
        return decode.decide(x, heights, sentence, pick, place, self.place.bin_yaw)

    def _act_forwards(self, x: torch.Tensor) -> tuple[decode.PickForward, decode.PlaceForward]:
        """The pick and place forwards acting on ``x`` runs: the CUDA graphs' replays where ``act_graphs`` applies
        and autocast is off, else the eager forwards."""
        if self._use("act_graphs") and not torch.is_autocast_enabled(x.device.type):
            return self._pick_graphs, self._place_graphs
        return self._pick_forward, self._place_forward

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):  # type: ignore[no-untyped-def]  # torch's hook
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        if self.centers_sentences:
            self._sentences_fitted = bool(self.sentence_scale > 0)

    def trainable_state_dict(self) -> dict[str, torch.Tensor]:
        """The state dict without any frozen encoder tensor."""
        return ckpt.trainable_state(self)

    def load_trainable_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Load weights saved by :meth:`trainable_state_dict` (every trainable tensor must be present)."""
        ckpt.load_trainable_state(self, state)

    def clip_source(self) -> str | None:
        """Where the frozen CLIP's weights came from, or None for agents without CLIP."""
        return None if self.encoder is None else self.encoder.sources().get("clip_weights")

    def weight_source_values(self) -> dict[str, str]:
        """``{config field: source}`` of every pretrained part (e.g. ``{"clip_weights": "openai"}``)."""
        return {field: getattr(self.config, field) for field in self.weight_sources}

    def similarity_heatmaps(self, obs: dict[str, np.ndarray], instruction: str) -> dict[str, np.ndarray]:
        """The text-image similarity maps the pick net reads for one observation, ``{text: (H, W)}``; empty for
        agents without them (only two_stream with ``similarity_maps`` has them)."""
        return {}

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
            "format": ckpt.CHECKPOINT_FORMAT,
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
        """Write ``folder/model.safetensors`` (trainable weights, no pickle) and ``folder/config.json`` (agent, config,
        weight sources); returns the folder, which :meth:`from_pretrained` loads. A training run's folder is refused
        (:func:`~cliport.agents.checkpoint.save_pretrained_folder`)."""
        return ckpt.save_pretrained_folder(self.checkpoint_payload(), folder)

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
        sources unless ``weights`` maps a source field to another (``{"clip_weights": "/other/path/RN50.pt"}``); a
        field the agent does not have is ignored. The agent is moved to ``device``.
        Called on an agent class (``TwoStreamAgent.from_pretrained``), the weights must be of that agent.
        """
        path = ckpt.pretrained_file(str(source), checkpoint)
        payload = ckpt.read_payload(path)
        if not issubclass(agent_class(payload["agent"]), cls):  # before any pretrained part is loaded
            raise CheckpointError(f"{path} holds a {payload['agent']} agent, not a {cls.name or cls.__name__} one")
        return _agent_from_payload(payload, path, device, weights)


def _agent_from_payload(
    payload: dict[str, Any], path: str, device: str | torch.device, weights: dict[str, str] | None
) -> PickPlaceAgent:
    """Build the agent a checkpoint payload describes (each pretrained part from the source ``weights`` names for it,
    else the recorded one), load its trainable weights and move it to ``device``; CheckpointError naming ``path``."""
    name = payload["agent"]
    config = dict(payload["config"])
    overrides = dict(weights or {})
    for field in agent_class(name).weight_sources:
        recorded = payload.get("weight_sources", {}).get(field) or payload.get(field)
        config[field] = overrides.get(field) or recorded or config.get(field)
    try:
        agent = make_agent(name, config)
    except ConfigError as e:
        raise CheckpointError(f"{path}: {e}") from e
    try:
        agent.load_trainable_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError) as e:
        raise CheckpointError(f"{path} does not match its recorded agent config: {e}") from e
    return agent.to(device)
