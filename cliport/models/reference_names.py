"""State-dict names of the reference CLIPort's agents and their counterparts in ours.

The reference (github.com/cliport/cliport) saves an agent's nets under ``attention.*`` (pick) and
``transport.*`` (place key and query). Our nets compute the same functions layer for layer, so every
trainable tensor of ours has exactly one reference tensor of the same shape; this module names it. It is
what `cliport-convert` and the parity tests use, and :func:`to_reference`/:func:`from_reference` check
the correspondence both ways (a missing, extra or differently shaped tensor is an error).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the names are read without torch (cliport-convert --help)
    import torch

#: Our agent name -> the reference's agent names (the first is its registry's preferred one).
REFERENCE_AGENTS: dict[str, tuple[str, ...]] = {
    "transporter_only": ("transporter",),
    "two_stream": ("cliport", "two_stream_clip_lingunet_lat_transporter"),
    "clip_only": ("clip_lingunet_transporter",),
}


#: Our prefix (within a net) of its own CLIP batch-norm statistics (``per_net_clip_stats``:
#: :class:`~cliport.models.encoder_net.PerNetClipStats`, saved under the net's ``encoder_stats``).
PER_NET_CLIP_STATS = "encoder_stats."


def _stages(ours: str, theirs: list[str]) -> list[tuple[str, str]]:
    return [(f"{ours}.{i}.", f"{ref}.") for i, ref in enumerate(theirs)]


def _resnet43() -> list[tuple[str, str]]:
    """ResNet43_8s: our Sequential's named sections stem/encoder/decoder/head, the reference's one ``layers``
    Sequential (its batch-norm placeholders, ReLUs and up-samplings take indices too)."""
    rules = [("resnet.stem.", "layers.0.")]
    for stage, first in enumerate((3, 5, 7, 9)):  # conv block, identity block
        rules += [(f"resnet.encoder.{stage}.{i}.", f"layers.{first + i}.") for i in (0, 1)]
    for stage, first in enumerate((11, 14, 17)):  # conv block, identity block, up-sampling
        rules += [(f"resnet.decoder.{stage}.0.{i}.", f"layers.{first + i}.") for i in (0, 1)]
    return rules + [("resnet.head.0.", "layers.20."), ("resnet.head.1.", "layers.21.")]


def _resnet45(ours: str) -> list[tuple[str, str]]:
    """ResNet45_10s: ours stem/encoder/decoder/head, the reference's conv1, layer1..10, conv2."""
    rules = [(f"{ours}.stem.", "conv1.0.")]
    rules += _stages(f"{ours}.encoder", [f"layer{i}" for i in range(1, 6)])
    for i in range(5):
        rules += [(f"{ours}.decoder.{i}.0.", f"layer{i + 6}.")]
    return rules + [(f"{ours}.head.", "conv2.")]


def _lingunet(ours: str, laterals: bool) -> list[tuple[str, str]]:
    """LingUNetDecoder / LingUNetLatDecoder (the reference's CLIPLingUNet(Lat), RN50BertLingUNetLat): ours
    sentence_fc/gates/bottleneck/ups/stages/fusions/out, the reference's text_fc, lang_proj1..3, conv1, up1..3,
    layer1..3, lat_fusion1..6, conv2."""
    rules = [(f"{ours}.sentence_fc.", "text_fc."), (f"{ours}.bottleneck.", "conv1."), (f"{ours}.out.", "conv2.0.")]
    for i in range(3):
        rules += [
            (f"{ours}.gates.{i}.", f"lang_proj{i + 1}."),
            (f"{ours}.ups.{i}.conv.", f"up{i + 1}.conv.double_conv."),
            (f"{ours}.stages.{i}.0.", f"layer{i + 1}."),
        ]
    if laterals:
        rules += [(f"{ours}.fusions.{i}.conv.", f"lat_fusion{i + 1}.conv.1.") for i in range(6)]
    return rules


@dataclass(frozen=True)
class _Net:
    ours: str  # our prefix of the net, e.g. "place.key_net."
    rules: tuple[tuple[str, str], ...]  # (our prefix within the net, the reference's full prefix)
    clip: str | None  # the reference's prefix of the net's own CLIP copy


#: Per agent: our net prefix and the reference's prefixes of its stream one, stream two and stream fusion.
_STREAMS: dict[str, list[tuple[str, str, str | None, str | None]]] = {
    "transporter_only": [
        ("pick.net.", "attention.attn_stream.", None, None),
        ("place.key_net.", "transport.key_resnet.", None, None),
        ("place.query_net.", "transport.query_resnet.", None, None),
    ],
    "two_stream": [
        ("pick.net.", "attention.attn_stream_one.", "attention.attn_stream_two.", None),
        ("place.key_net.", "transport.key_stream_one.", "transport.key_stream_two.", "transport.fusion_key."),
        ("place.query_net.", "transport.query_stream_one.", "transport.query_stream_two.", "transport.fusion_query."),
    ],
    "clip_only": [
        ("pick.net.", "attention.attn_stream_one.", None, None),
        ("place.key_net.", "transport.key_stream_one.", None, None),
        ("place.query_net.", "transport.query_stream_one.", None, None),
    ],
}


def _nets(agent: str) -> list[_Net]:
    if agent not in _STREAMS:
        raise KeyError(f"no reference counterpart for agent {agent!r}; agents with one: {sorted(REFERENCE_AGENTS)}")
    nets = []
    clips = frozen_prefixes(agent) or (None,) * len(_STREAMS[agent])
    for (ours, one, two, fusion), clip in zip(_STREAMS[agent], clips, strict=True):
        if agent == "transporter_only":
            rules = [(a, one + b) for a, b in _resnet43()]
        elif agent == "clip_only":
            rules = [(a, one + b) for a, b in _lingunet("semantic", laterals=False)]
        else:
            assert two is not None
            rules = [(a, one + b) for a, b in _resnet45("spatial")]
            rules += [(a, two + b) for a, b in _lingunet("semantic", laterals=True)]
            if fusion is not None:
                rules.append(("fuse.", fusion + "conv.1."))
        nets.append(_Net(ours, tuple(rules), clip))
    return nets


def reference_name(agent: str, key: str) -> str:
    """The reference's state-dict key of our agent's key (``ValueError`` if it has none)."""
    for net in _nets(agent):
        if not key.startswith(net.ours):
            continue
        inner = key[len(net.ours) :]
        if inner.startswith(PER_NET_CLIP_STATS) and net.clip is not None:  # the net's own CLIP batch-norm statistics
            return net.clip + "visual." + inner[len(PER_NET_CLIP_STATS) :].replace("__", ".")
        matches = [(a, b) for a, b in net.rules if inner.startswith(a)]
        if matches:
            ours, theirs = max(matches, key=lambda rule: len(rule[0]))
            name = theirs + inner[len(ours) :]
            return name.replace(".shortcut.weight", ".shortcut.0.weight")
    raise ValueError(f"{key} of the {agent} agent has no counterpart in the reference")


def frozen_prefixes(agent: str) -> tuple[str, ...]:
    """The reference's prefixes of frozen encoder tensors (its per-net CLIP copies), in the order pick,
    key, query."""
    if agent == "transporter_only":
        return ()
    semantic = 2 if agent == "two_stream" else 1  # the stream that holds the CLIP copy
    return tuple(f"{stream}clip_rn50." for streams in _STREAMS[agent] if (stream := streams[semantic]) is not None)


def from_reference(
    agent: str, reference: dict[str, torch.Tensor], ours: dict[str, torch.Tensor]
) -> dict[str, torch.Tensor]:
    """Our agent's trainable state dict from a reference state dict.

    ``ours``: our agent's trainable state dict (names and shapes to fill). Reference tensors under
    :func:`frozen_prefixes` are ignored; any other reference tensor left over, any of ours missing, and
    any shape mismatch is a ``ValueError`` naming the tensors.
    """
    frozen = frozen_prefixes(agent)
    names = {key: reference_name(agent, key) for key in ours}
    missing = sorted(ref for ref in names.values() if ref not in reference)
    wanted = set(names.values())
    leftover = sorted(k for k in reference if k not in wanted and not (frozen and k.startswith(frozen)))
    wrong = [
        f"{ref} {tuple(reference[ref].shape)} for {key} {tuple(ours[key].shape)}"
        for key, ref in names.items()
        if ref in reference and reference[ref].shape != ours[key].shape
    ]
    if missing or leftover or wrong:
        problems = []
        if missing:
            problems.append(f"missing {len(missing)} tensors (e.g. {', '.join(missing[:3])})")
        if leftover:
            problems.append(f"{len(leftover)} unknown tensors (e.g. {', '.join(leftover[:3])})")
        if wrong:
            problems.append(f"{len(wrong)} of another shape (e.g. {'; '.join(wrong[:2])})")
        raise ValueError(f"not a reference {REFERENCE_AGENTS[agent][0]} state dict: " + ", ".join(problems))
    return {key: reference[ref].detach().clone() for key, ref in names.items()}


def to_reference(agent: str, ours: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Our agent's trainable state dict under the reference's names (frozen encoders not included)."""
    return {reference_name(agent, key): value for key, value in ours.items()}
