"""The base of the nets that read a shared frozen encoder, and each net's own copy of its batch-norm statistics.

:class:`EncoderNet` is the base of :class:`~cliport.models.semantic.SemanticNet` and
:class:`~cliport.models.two_stream.TwoStreamNet`; the encoder itself (a
:class:`~cliport.models.encoders.base.FrozenEncoder`) is loaded by :mod:`cliport.models.encoders`.
"""

from __future__ import annotations

import torch
from torch import nn

from cliport.models.distinct_images import DistinctImages, distinct_images
from cliport.models.encoders.base import FrozenEncoder


class PerNetClipStats(nn.Module):
    """One net's own batch-norm statistics for a shared frozen encoder's image trunk (buffers, saved in
    checkpoints with the net's weights): the agents' ``per_net_clip_stats``. Names are those of
    :meth:`FrozenEncoder.norm_stats`, with ``__`` for ``.``."""

    def __init__(self, stats: dict[str, torch.Tensor]) -> None:
        super().__init__()
        for name, value in stats.items():
            self.register_buffer(name.replace(".", "__"), value.detach().clone().float())

    def as_dict(self) -> dict[str, torch.Tensor]:
        """``{trunk buffer name: tensor}``."""
        return {name.replace("__", "."): value for name, value in self.named_buffers()}


class EncoderNet(nn.Module):
    """Base of the nets that read a shared frozen encoder (:class:`~cliport.models.semantic.SemanticNet`,
    :class:`~cliport.models.two_stream.TwoStreamNet`).

    The encoder is shared by an agent's pick, key and query nets and is no trainable part of any of them.
    ``per_net_clip_stats``: the net keeps its own copy of the encoder trunk's batch-norm statistics
    (:class:`PerNetClipStats`, attribute ``encoder_stats``: the name saved checkpoints hold them under),
    as the reference's three CLIP copies (pick, key, query) do: each lets its statistics drift in
    training, and its checkpoints act with each net's own.
    """

    def __init__(self, encoder: FrozenEncoder, per_net_clip_stats: bool = False) -> None:
        super().__init__()
        self.encoder = encoder
        self.encoder_stats = PerNetClipStats(encoder.norm_stats()) if per_net_clip_stats else None
        #: Images per sample in this net's batches: n_rotations in a place head's query net (set by PlaceHead).
        self.samples_per_group = 1
        self.train_encoder_norms = False  # see set_encoder_norm_training

    def set_encoder_norm_training(self, enabled: bool) -> bool:
        """Whether training forwards run the encoder trunk's batch norms in training mode on this net's own
        statistics (see :meth:`encoder_features`); only a net with ``per_net_clip_stats`` can. Returns
        whether it now does."""
        self.train_encoder_norms = enabled and self.encoder_stats is not None
        return self.train_encoder_norms

    def encoder_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The frozen encoder's five trunk levels of the RGB channels of x (N, 6, H, W), with the net's own
        batch-norm statistics when it keeps them. In training mode with :meth:`set_encoder_norm_training`
        on (the cliport recipe), the trunk's batch norms normalise each sample's images
        (:attr:`samples_per_group`) by their own statistics and update the net's running statistics."""
        stats = self.encoder_stats.as_dict() if self.encoder_stats is not None else None
        group = self.samples_per_group if self.training and self.train_encoder_norms else None
        return self.encoder.image_features(x[:, :3], stats, batch_stats_group=group)

    def distinct_inputs(self, x: torch.Tensor) -> DistinctImages | None:
        """The distinct images of a raw batch (N, 6, H, W) and each sample's among them
        (:func:`~cliport.models.distinct_images.distinct_images`), or None: every image differs, or the trunk's
        batch norms train on this call (each sample's pass updates the statistics, as a reference step would)."""
        if self.training and self.train_encoder_norms:
            return None
        return distinct_images(x)
