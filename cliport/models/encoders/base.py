"""The frozen pretrained part of a semantic stream: an image trunk and a sentence encoder.

Every semantic stream (CLIPort's two-stream nets, the CLIP-only and RN50-BERT ablations) reads a
:class:`FrozenEncoder`: a multi-scale image trunk and a sentence encoder whose weights never train.
One instance is shared by the pick, key and query nets of an agent. Subclasses say how many
channels each trunk level has and how wide the sentence feature is; the trainable decoder is built
from those numbers.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator

import torch
from torch import nn

log = logging.getLogger(__name__)
# (encoder class, instruction) pairs already warned about, so that a long instruction is named once.
_warned: set[tuple[str, str]] = set()

#: Strides of the five trunk levels every encoder returns: stem, layer1, layer2, layer3, layer4.
TRUNK_STRIDES = (4, 4, 8, 16, 32)
#: How many recent images :meth:`FrozenEncoder.image_features` keeps the trunk features of, on these devices (not
#: CUDA: comparing images reads the device, which a captured CUDA graph must never do).
RECENT_IMAGES = 4
RECENT_IMAGE_DEVICES = {"cpu"}
# Guards every encoder's recent images: the pick and place halves of a step run in two threads at once. One lock
# for all (not one per encoder) so that an encoder can still be deep-copied and pickled.
_recent_lock = threading.Lock()


class FrozenEncoder(nn.Module):
    """Base of the frozen encoders: always in eval mode, no gradients, sentence features cached.

    Subclasses set ``trunk_channels`` (five ints, one per level of :data:`TRUNK_STRIDES`) and
    ``sentence_dim``, implement :meth:`_trunk`, :meth:`_encode_sentences`, :meth:`image_module` and
    :meth:`sources`, and call :meth:`freeze` at the end of ``__init__``.
    """

    trunk_channels: tuple[int, int, int, int, int]
    sentence_dim: int
    #: Width of a trainable Linear each decoder puts on the sentence feature before its language gates
    #: (RN50-BERT: DistilBERT's 768 -> 1024, as in CLIPort), or None to gate with the feature itself.
    sentence_projection: int | None = None

    def __init__(self) -> None:
        super().__init__()
        self._sentence_cache: dict[str, torch.Tensor] = {}
        # The image trunk's float32 weights (on the CPU) while it runs in a lower precision.
        self._fp32_image_state: dict[str, torch.Tensor] | None = None
        # (image, its trunk features) of the last RECENT_IMAGES CPU calls with the trunk's own statistics, newest
        # last.
        self._recent: list[tuple[torch.Tensor, list[torch.Tensor]]] = []

    def freeze(self) -> None:
        """No gradients and eval mode for every submodule (batch-norm statistics never drift)."""
        self.requires_grad_(False)
        super().train(False)

    def train(self, mode: bool = True) -> FrozenEncoder:
        """Stay in eval mode whatever is asked."""
        return super().train(False)

    def sources(self) -> dict[str, str]:
        """``{agent config field: weight source}`` of each pretrained part, e.g. ``{"clip_weights": "openai"}``."""
        raise NotImplementedError

    def dense_embeddings(self, layer4: torch.Tensor) -> torch.Tensor:
        """The last trunk level (N, C, h, w) -> text-aligned embeddings (N, sentence_dim, h, w) at each position;
        only encoders whose image and text share an embedding space (CLIP) have them."""
        raise ValueError(f"{type(self).__name__} has no image-text embedding space: similarity maps need a CLIP")

    def logit_scale(self) -> float:
        """The inverse temperature of the encoder's image-text logits (CLIP's learned ``logit_scale``, exp'd)."""
        raise ValueError(f"{type(self).__name__} has no image-text embedding space: similarity maps need a CLIP")

    def image_module(self) -> nn.Module:
        """The image trunk's module (its dtype is switched to bfloat16 on CUDA, see :meth:`set_image_dtype`)."""
        raise NotImplementedError

    def set_image_dtype(self, dtype: torch.dtype) -> None:
        """Run the image trunk in ``dtype`` (its features are still returned as float32).

        Reversible: leaving float32 keeps a CPU copy of the float32 weights, and coming back to float32
        restores them exactly (a bfloat16 round trip alone would leave every weight rounded).
        """
        module = self.image_module()
        self.forget_images()
        if dtype != torch.float32:
            if self._fp32_image_state is None and self.image_dtype() == torch.float32:
                self._fp32_image_state = {k: v.detach().to("cpu", copy=True) for k, v in module.state_dict().items()}
            module.to(dtype)
            return
        module.to(torch.float32)
        if self._fp32_image_state is not None:
            module.load_state_dict(self._fp32_image_state)
            self._fp32_image_state = None

    def instruction_note(self, text: str) -> str | None:
        """A sentence for the user when the encoder cannot read all of ``text`` (e.g. too many tokens);
        :meth:`sentence_features` logs it once per instruction as a warning."""
        return None

    def image_dtype(self) -> torch.dtype:
        """The dtype the image trunk runs in."""
        return next(self.image_module().parameters()).dtype

    def _trunk(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """RGB (N, 3, H, W) float32 in [0, 1] -> the five trunk levels (normalise, then cast to
        :meth:`image_dtype`)."""
        raise NotImplementedError

    def _encode_sentences(self, texts: list[str]) -> torch.Tensor:
        """Distinct instructions (B,) -> (B, sentence_dim) on the encoder's device."""
        raise NotImplementedError

    @torch.no_grad()
    def image_features(
        self,
        rgb: torch.Tensor,
        norm_stats: dict[str, torch.Tensor] | None = None,
        batch_stats_group: int | None = None,
    ) -> list[torch.Tensor]:
        """Trunk features of RGB images with values in [0, 1] (H, W multiples of 32).

        (N, 3, H, W) -> five float32 maps (N, trunk_channels[i], H / s, W / s) for the strides s of
        :data:`TRUNK_STRIDES`. ``norm_stats``: batch-norm statistics to use instead of the trunk's own for
        this call (names as in :meth:`norm_stats`), e.g. one net's of a converted reference checkpoint.
        ``batch_stats_group``: run the batch norms in training mode, each group of that many consecutive
        images normalised by its own statistics, and update the running statistics (``norm_stats``' tensors,
        in place) group after group, as that many reference steps of one sample each would (the reference
        CLIPort's training steps put its CLIP copies in training mode). Weights never change.

        On the CPU, with the trunk's own statistics, the features of the last :data:`RECENT_IMAGES` images are
        kept and an equal image (every value) gets them again instead of a second pass: a contrasting pair's
        two steps (``pair_contrasts``) show the pick and key nets one augmented image. A batch of one image
        repeated (a held-out check's scene under its six instructions) runs the trunk on one copy. The features
        are the same tensors (expanded views for a repeated image); callers must not write into them.
        """
        stats = norm_stats or {}
        if batch_stats_group is None:
            if stats or rgb.device.type not in RECENT_IMAGE_DEVICES:
                with self._swapped_buffers(stats):
                    return [f.float() for f in self._trunk(rgb.float())]
            return self._recent_features(rgb)
        with self._swapped_buffers(stats, write_back=True), self._norms_training():
            groups = [self._trunk(chunk) for chunk in rgb.float().split(batch_stats_group)]
        return [torch.cat(levels).float() for levels in zip(*groups, strict=True)]

    def _recent_features(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        with _recent_lock:
            for i, (seen, features) in enumerate(self._recent):
                if seen.shape == rgb.shape and seen.dtype == rgb.dtype and torch.equal(seen, rgb):
                    self._recent.append(self._recent.pop(i))
                    return features
        n = rgb.shape[0]
        if n > 1 and torch.equal(rgb, rgb[:1].expand_as(rgb)):
            features = [f.float().expand(n, *f.shape[1:]) for f in self._trunk(rgb[:1].float())]
        else:
            features = [f.float() for f in self._trunk(rgb.float())]
        with _recent_lock:
            self._recent.append((rgb.detach().clone(), features))
            del self._recent[:-RECENT_IMAGES]
        return features

    def forget_images(self) -> None:
        """Drop the kept trunk features of recent images (see :meth:`image_features`); done whenever the
        trunk's weights, dtype or device change."""
        with _recent_lock:
            self._recent.clear()

    @contextlib.contextmanager
    def _norms_training(self) -> Iterator[None]:
        norms = [m for m in self.image_module().modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
        try:
            for norm in norms:
                norm.train(True)
            yield
        finally:
            for norm in norms:
                norm.train(False)

    def norm_stats(self) -> dict[str, torch.Tensor]:
        """The running means and variances of the image trunk's batch norms, by name within
        :meth:`image_module` (empty for a trunk without batch norms)."""
        return {
            name: buffer
            for name, buffer in self.image_module().named_buffers()
            if name.endswith((".running_mean", ".running_var")) or name in ("running_mean", "running_var")
        }

    @contextlib.contextmanager
    def _swapped_buffers(self, buffers: dict[str, torch.Tensor], write_back: bool = False) -> Iterator[None]:
        # Not thread-safe: an agent runs one forward at a time (see Predictor). With ``write_back``, values
        # the trunk changed in a converted copy (another dtype or device) are copied back into ``buffers``.
        module = self.image_module()
        saved = []
        try:
            for name, value in buffers.items():
                owner_name, _, attr = name.rpartition(".")
                owner = module.get_submodule(owner_name)
                current = owner._buffers[attr]
                if current is None:
                    raise KeyError(f"the image trunk has no buffer {name}")
                saved.append((owner, attr, current, value))
                owner._buffers[attr] = value.to(device=current.device, dtype=current.dtype)
            yield
        finally:
            for owner, attr, original, value in saved:
                current = owner._buffers[attr]
                if write_back and current is not None and current is not value:
                    value.copy_(current)
                owner._buffers[attr] = original

    @torch.no_grad()
    def sentence_features(self, texts: list[str]) -> torch.Tensor:
        """Sentence vectors of ``texts``, (B,) -> (B, sentence_dim) float32, each distinct string encoded once
        (alone) and cached."""
        # One string at a time: a feature must not depend on which other strings shared its batch
        # (batched matrix products round differently), or a reloaded agent would act differently.
        for text in sorted({t for t in texts if t not in self._sentence_cache}):
            note = self.instruction_note(text)
            if note is not None and (type(self).__name__, text) not in _warned:
                _warned.add((type(self).__name__, text))
                log.warning("%s, the rest is ignored: %r", note, text)
            self._sentence_cache[text] = self._encode_sentences([text])[0].float()
        return torch.stack([self._sentence_cache[t] for t in texts])

    def _apply(self, fn, recurse: bool = True):  # type: ignore[no-untyped-def]  # torch's private hook, untyped
        self._sentence_cache.clear()
        self.forget_images()
        return super()._apply(fn, recurse)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):  # type: ignore[no-untyped-def]  # torch's hook
        self.forget_images()
        # Weights loaded into a bfloat16 trunk also replace the float32 copy it will be restored from.
        if self._fp32_image_state is not None:
            module = self.image_module()
            name = next(n for n, m in self.named_modules() if m is module)
            for key in self._fp32_image_state:
                full = f"{prefix}{name}.{key}" if name else f"{prefix}{key}"
                if full in state_dict:
                    self._fp32_image_state[key] = state_dict[full].detach().to("cpu", torch.float32, copy=True)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
