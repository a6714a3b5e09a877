"""A first initialisation that can learn: a net that is dead before any update is drawn again.

The key and query nets of two_stream and rn50_bert end in the reference's ``FusionConv``: a ReLU over the two
streams' few output channels (3 each), then a 1x1 conv. Under some initial weights all three channels of a
stream are negative at every pixel. The ReLU zeroes that stream and no gradient ever reaches it: a dead
semantic stream is a place net that cannot read the sentence, and two dead streams leave the place map
constant. At the language lesson's size, seed 10 draws a constant place map, and seed 0 a key net whose
semantic stream is dead; that seed's place net never learned the bowl word (docs/language-lesson.md).

:func:`ensure_live` forwards one training sample before the first step and re-initialises a dead net's
trainable layers from a new seed, with their own initialisers (the same distributions as the first draw),
until it is live. The net stays the reference's net; only the draw of its weights changes, and the run's
summary records it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import nn

from cliport.agents.base import PickPlaceAgent, TrainingInputs
from cliport.errors import UserError
from cliport.models.fusion import ConvFusion
from cliport.models.preprocess import raw_input

#: Draws tried per net before giving up.
MAX_DRAWS = 32
#: The stride between the seeds of successive draws (draw ``k`` of a net first drawn from seed ``s`` uses
#: ``s + (k - 1) * stride``).
DRAW_SEED_STRIDE = 7_777_777
_NETS = ("pick", "place")


class DeadStartError(UserError, RuntimeError):
    """Every draw tried left a net unable to learn (:func:`dead_nets`)."""


def dead_nets(agent: PickPlaceAgent, inputs: TrainingInputs) -> dict[str, str]:
    """The nets ("pick", "place") that cannot learn from where they start, each with the reason: an output map on
    ``inputs`` (:meth:`PickPlaceAgent.training_inputs` of one batch) that is the same at every pixel and rotation,
    or a stream whose every channel a stream fusion's ReLU zeroes at every pixel (that stream gets no gradient).
    Forwarded in the agent's current mode; batch-norm running statistics are left as they were."""
    found: dict[str, str] = {}
    hooks = []
    for name in _NETS:
        for path, module in getattr(agent, name).named_modules():
            if isinstance(module, ConvFusion):

                def look(_: nn.Module, streams: tuple[torch.Tensor, ...], net: str = name, at: str = path) -> None:
                    for stream, output in zip(("spatial", "semantic"), streams, strict=True):
                        if net not in found and not bool((output > 0).any()):
                            found[net] = f"its {at}'s {stream} stream is negative everywhere, so the ReLU zeroes it"

                hooks.append(module.register_forward_pre_hook(look))
    buffers = [(b, b.clone()) for b in agent.buffers()]
    try:
        with torch.no_grad():
            x = raw_input(inputs["color"], inputs["height"])
            maps = {
                "pick": agent.pick(x, inputs["sentence"]),
                "place": agent.place(x, inputs["pick_pix"], inputs["sentence"]),
            }
    finally:
        for hook in hooks:
            hook.remove()
        with torch.no_grad():
            for buffer, saved in buffers:
                buffer.copy_(saved)
    for name, out in maps.items():
        flat = out.reshape(out.shape[0], -1)
        if bool((flat.amax(1) == flat.amin(1)).any()):
            found[name] = "its output map is constant"
    return {name: found[name] for name in _NETS if name in found}


def redraw(net: nn.Module, seed: int) -> None:
    """Re-initialise every trainable layer of ``net`` (``reset_parameters``) from ``seed``; frozen layers (the
    pretrained encoder) are left alone, and the global random state is as it was."""
    layers = [
        m for m in net.modules() if (own := list(m.parameters(recurse=False))) and all(p.requires_grad for p in own)
    ]
    resets: list[Callable[[], None]] = []
    for layer in layers:
        if not callable(reset := getattr(layer, "reset_parameters", None)):
            raise TypeError(f"cannot re-initialise {type(layer).__name__}: it has no reset_parameters()")
        resets.append(reset)
    devices = sorted({p.device.index or 0 for p in net.parameters() if p.device.type == "cuda"})
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(seed)
        for reset in resets:
            reset()


def ensure_live(agent: PickPlaceAgent, inputs: TrainingInputs, seed: int) -> dict[str, dict[str, Any]]:
    """Draw each net :func:`dead_nets` finds on ``inputs`` again (:func:`redraw`, draw ``k`` from
    ``seed + (k - 1) * DRAW_SEED_STRIDE``) until none is found; returns, per redrawn net, the draw it ended at
    and why the first was dead ({} when every first draw was live). Raises :class:`DeadStartError` after
    :data:`MAX_DRAWS` draws of one net."""
    redrawn: dict[str, dict[str, Any]] = {}
    dead = dead_nets(agent, inputs)
    while dead:
        for name, reason in dead.items():
            record = redrawn.setdefault(name, {"draws": 1, "reason": reason})
            record["draws"] += 1
            if record["draws"] > MAX_DRAWS:
                raise DeadStartError(
                    f"the {name} net cannot learn from this input under any of {MAX_DRAWS} initialisations ({reason}); "
                    "check the demonstrations' images and heights"
                )
            redraw(getattr(agent, name), seed + (record["draws"] - 1) * DRAW_SEED_STRIDE)
        dead = dead_nets(agent, inputs)
    return redrawn
