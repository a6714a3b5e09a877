"""The settings of the pick-and-place agents: what every agent has (:class:`AgentConfig`) and each family's
own (its subclasses). They import no torch and no agent, so that the console scripts derive their flags
(and ``--help``) from them alone; the registry (:data:`cliport.agents.registry.AGENTS`) says which agent
takes which.

Defaults live in ``configs/<agent name>.toml``; :func:`cliport.agents.make_agent` reads them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar


@dataclass
class AgentConfig:
    """Settings shared by every agent.

    Args:
        n_rotations: place rotation bins (bin k = relative yaw k * 2*pi / n_rotations).
        crop_size: side in pixels of the query crop around the pick pixel (even; also the key map's padding x 2).
        lr: Adam learning rate.
        width: channel-width multiplier of the trainable nets; 1.0 is the published size, small values make
            tiny test nets.
        map_scale: the nets run on the top-down map shrunk by this factor (area averaging; the query crop
            shrinks alike) and their logits are grown back bilinearly, so heatmaps, pixels and labels keep
            the map's size. 1.0 (the reference) or 0.5 (6.25 mm cells: a CPU step about 3x cheaper).
    """

    #: The fields that name pretrained weights (recorded in checkpoints, never saved in them); an agent's
    #: ``weight_sources`` are its config's.
    weight_sources: ClassVar[tuple[str, ...]] = ()

    n_rotations: int
    crop_size: int
    lr: float
    width: float
    map_scale: float

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the fields (what checkpoints store)."""
        return dataclasses.asdict(self)

    def validate(self) -> None:
        """Raise ConfigError for values no agent can be built with."""
        from cliport.errors import ConfigError

        if self.width <= 0:
            raise ConfigError(f"width must be > 0, got {self.width}")
        if self.n_rotations < 1:
            raise ConfigError(f"n_rotations must be >= 1, got {self.n_rotations}")
        if self.crop_size < 2 or self.crop_size % 2:
            raise ConfigError(f"crop_size must be an even number >= 2, got {self.crop_size}")
        if self.lr <= 0:
            raise ConfigError(f"lr must be > 0, got {self.lr}")
        if self.map_scale not in (1.0, 0.5):
            raise ConfigError(f"map_scale must be 1.0 (the reference) or 0.5, got {self.map_scale}")


@dataclass
class LanguageConfig(AgentConfig):
    """Settings of agents that read an instruction; as :class:`AgentConfig` plus

    Args:
        center_sentences: the nets read the frozen encoder's sentence features centred on the mean of the
            training set's distinct instructions and rescaled by their RMS norm over their centred RMS norm
            (fitted once when training starts, saved with the weights), so that what the instructions share
            does not drown what tells them apart. Not the reference's: it reads the raw features.
        scale_up_mid: below width 1, the middle width of the decoder's three up-blocks (the reference's in_ch // 2)
            shrinks with ``width`` too, as every other width the decoder owns does: ``width`` x (the reference's
            middle width at width 1), e.g. 128, 64 and 32 at width 0.125 over a ResNet-50 trunk. False: half the
            narrowed input, whose skip from the frozen trunk does not narrow (576, 288 and 144 there), so the
            first convolutions over the skips take about half a width-0.125 step's arithmetic. The same net at
            width 1 either way (the reference's).
    """

    center_sentences: bool
    scale_up_mid: bool


@dataclass
class CLIPConfig(LanguageConfig):
    """Settings of agents with a frozen CLIP; as :class:`LanguageConfig` plus

    Args:
        clip_weights: "openai" (the published weights: Hugging Face cache, else download), another of the
            model's open_clip pretrained tags, a local weights file of the model, or "random" (seeded; tests
            and benchmarks only, recorded as such).
        semantic_encoder: the open_clip model of the semantic stream, any with a text tower whose tokenizer
            ships with open_clip: "RN50-quickgelu" (CLIPort's), "RN101-quickgelu", "ViT-B-16", ...
        per_net_clip_stats: each net (pick, key, query) keeps its own copy of the CLIP trunk's batch-norm
            statistics, as the reference's checkpoints do (cliport-convert sets it); false: the one
            shared CLIP's own statistics.
        similarity_maps: two_stream only: the cosine similarity of CLIP's dense text-aligned image embeddings
            with the instruction's and its first two phrases' text embeddings (three maps at the trunk's last
            level) joins every spatial lateral of the semantic decoder, so that the nets can find a word where
            CLIP's shared image-text space places it, seen in the demos or not. Not the reference's net.
        similarity_scale: with ``similarity_maps``, the trunk reads the nets' image resized by this factor (its
            sides rounded to multiples of 32) for the maps alone: at stride 32 a block of the half-size CPU map
            spans a fifth of a cell, and a finer map finds it more often (docs/results/pretraining.md).
        similarity_bank: with ``similarity_maps``, each map is at every position the probability (CLIP's
            softmax at its own temperature) that the text, rather than any of the training instructions' phrases
            (a bank fitted when training starts, saved with the weights), describes it best, instead of the raw
            cosine: "the red block" then lights the red block, not every block alike (docs/results/pretraining.md).
        language_gates: the semantic decoder's layers are gated by the sentence feature, as CLIPort's are; false
            (needs ``similarity_maps``): they read a zero sentence feature, so that the instruction reaches the
            nets through the similarity maps alone, where a word unseen in the demos still finds its colour.
        gate_phrase_dropout: with ``similarity_bank`` and the gates, above 0: the sentence the gates read loses a
            phrase's describing words ("the pink block" -> "the block") with this probability per phrase in
            training, and at act time whenever the phrase bank was not fitted on that phrase, so that the gates
            read the words the demos showed and the maps the others (the maps always read every phrase).
    """

    weight_sources: ClassVar[tuple[str, ...]] = ("clip_weights",)

    clip_weights: str
    semantic_encoder: str
    per_net_clip_stats: bool
    similarity_maps: bool
    similarity_scale: float
    similarity_bank: bool
    language_gates: bool
    gate_phrase_dropout: float

    def validate(self) -> None:
        """As :meth:`AgentConfig.validate`, the similarity scale positive, and the encoder name an open_clip
        model we can use."""
        super().validate()
        from cliport.errors import ConfigError

        if not self.similarity_scale > 0:
            raise ConfigError(f"similarity_scale must be positive, got {self.similarity_scale}")
        if self.similarity_bank and not self.similarity_maps:
            raise ConfigError("similarity_bank = true needs similarity_maps, the maps it makes probabilities of")
        if not self.language_gates and not self.similarity_maps:
            raise ConfigError("language_gates = false needs similarity_maps: without both the nets read no instruction")
        if not 0 <= self.gate_phrase_dropout < 1:
            raise ConfigError(f"gate_phrase_dropout is a probability below 1, got {self.gate_phrase_dropout}")
        if self.gate_phrase_dropout and not (self.similarity_bank and self.language_gates):
            raise ConfigError(
                "gate_phrase_dropout needs similarity_bank (the phrases the demos showed) and language_gates (the "
                "sentence it drops phrases from)"
            )
        from cliport.models.encoders.clip_registry import check_model_name

        check_model_name(self.semantic_encoder)


@dataclass
class RN50BERTConfig(LanguageConfig):
    """Settings of the RN50-BERT agent; as :class:`LanguageConfig` plus

    Args:
        rn50_weights: "imagenet" (torchvision's ImageNet weights: torch's hub cache, else download), a local
            torchvision resnet50 state-dict file, or "random" (seeded; tests and benchmarks only).
        bert_weights: "distilbert-base-uncased" (or another Hugging Face DistilBERT repo id: the HF cache,
            else download), a local folder written by save_pretrained (model + tokenizer), or "random"
            (seeded, with a word-hashing tokenizer; tests and benchmarks only).
    """

    weight_sources: ClassVar[tuple[str, ...]] = ("rn50_weights", "bert_weights")

    rn50_weights: str
    bert_weights: str
