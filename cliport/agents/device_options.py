"""An agent's per-device speed settings (``PickPlaceAgent.optimize_for_device``): which apply where, and
putting the layout and precision ones into effect on the nets.

- ``channels_last``: the heads' weights and inputs (raw input, padded key input, query crops) in
  channels_last, so cuDNN never converts layouts;
- ``bf16_clip``: the frozen encoder's image trunk in bfloat16 (features returned as float32, the text encoder
  float32), on GPUs that compute bf16 natively (compute capability 8.0+);
- ``fused_adam``: the fused Adam kernel in ``make_optimizer`` (CUDA and CPU: on the lesson's two_stream, 34.5 M
  trainable values, one CPU Adam step takes 20 ms fused and 64 ms foreach);
- ``act_graphs``: ``act_batch``'s pick and place forwards replayed as CUDA graphs
  (:class:`~cliport.models.cuda_graphs.GraphedForward`).

Each applies on CUDA only, but ``fused_adam``, which applies on the CPU too.
"""

from __future__ import annotations

import torch

from cliport.models.encoders.base import FrozenEncoder
from cliport.models.heads import PickHead, PlaceHead
from cliport.utils.device import bf16_native

DEVICE_OPTIONS = ("channels_last", "bf16_clip", "fused_adam", "act_graphs")


def option_applies(requested: dict[str, bool], option: str, device: torch.device) -> bool:
    """Whether ``option`` is in effect on ``device`` when ``requested`` (``{option: asked for}``) holds."""
    if not requested[option]:
        return False
    if option == "fused_adam":
        return device.type in ("cuda", "cpu")
    if device.type != "cuda":
        return False
    return option != "bf16_clip" or bf16_native(device)


def apply_layout_and_precision(
    heads: tuple[PickHead | PlaceHead, ...], encoder: FrozenEncoder | None, channels_last: bool, bf16: bool
) -> None:
    """Put the heads' weights and inputs in channels_last (or contiguous) memory format and the encoder's
    image trunk in bfloat16 (or float32, its weights restored)."""
    layout = torch.channels_last if channels_last else torch.contiguous_format
    for head in heads:
        head.to(memory_format=layout)
        head.input_memory_format = layout
    if encoder is not None:
        encoder.set_image_dtype(torch.bfloat16 if bf16 else torch.float32)
