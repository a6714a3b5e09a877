"""Print JSON with the trainable and frozen parameter counts of every registered agent at its real size,
next to the reference CLIPort code's own counts.

Pretrained parts are random-initialised here (counts do not depend on the weights), so no download is
needed. The reference counts are computed layer by layer from the reference's module definitions
(CLIPort's ``resnet.py``, ``resnet_lat.py``, ``core/unet.py``, ``core/fusion.py``, ``clip_lingunet*.py``,
``rn50_bert_lingunet_lat.py``) with its training config (``batchnorm: False``: residual blocks without
batch norm and without conv biases; the U-Net up-blocks keep their two batch norms and conv biases).
Frozen encoders are left out of both: the reference's CLIP and BERT sit in the nets without gradients.
"""

from __future__ import annotations

import json

from torch import nn

from cliport.agents import agent_class, agent_names, make_agent


def _count(module: nn.Module, trainable: bool) -> int:
    return sum(p.numel() for p in module.parameters() if p.requires_grad == trainable)


def _conv(cin: int, cout: int, k: int = 1, bias: bool = False) -> int:
    return cin * cout * k * k + (cout if bias else 0)


def _stage(cin: int, w: int, out: int | None = None) -> int:
    """Reference ConvBlock + IdentityBlock (1x1, 3x3, 1x1 bottlenecks, no biases) with ``out`` channels."""
    out = w if out is None else out
    conv_block = _conv(cin, w) + _conv(w, w, 3) + _conv(w, out) + _conv(cin, out)
    return conv_block + _conv(out, w) + _conv(w, w, 3) + _conv(w, out)


def _up(cin: int, cout: int) -> int:
    """Reference U-Net Up block: DoubleConv(cin -> cin/2 -> cout), 3x3 convs with biases and batch norms."""
    mid = cin // 2
    return _conv(cin, mid, 3, True) + 2 * mid + _conv(mid, cout, 3, True) + 2 * cout


def _resnet43(out: int) -> int:
    widths = [(64, 64), (64, 128), (128, 256), (256, 512), (512, 256), (256, 128), (128, 64)]
    return _conv(6, 64, 3, True) + sum(_stage(i, w) for i, w in widths) + _stage(64, 16, out)


def _resnet45(out: int) -> int:
    widths = [(64, 64), (64, 128), (128, 256), (256, 512), (512, 1024), (1024, 512), (512, 256), (256, 128)]
    widths += [(128, 64), (64, 32)]
    return _conv(6, 64, 3, True) + sum(_stage(i, w) for i, w in widths) + _stage(32, 16, out)


def _lingunet(out: int, laterals: bool, text_fc: bool) -> int:
    n = sum(1024 * w + w for w in (1024, 512, 256))  # language projections
    n += _conv(2048, 1024, 3) + _up(2048, 512) + _up(1024, 256) + _up(512, 128)
    n += _stage(128, 64) + _stage(64, 32) + _stage(32, 16) + _conv(16, out, 1, True)
    if laterals:
        n += sum(_conv(a + b, b) for a, b in [(1024, 512), (512, 256), (256, 128), (128, 64), (64, 32), (32, 16)])
    if text_fc:
        n += 768 * 1024 + 1024  # DistilBERT feature -> 1024
    return n


def _two_stream(out: int, text_fc: bool = False) -> int:
    fusion = _conv(2 * out, out) if out > 1 else 0  # key/query: ReLU + 1x1 conv; pick: addition
    return _resnet45(out) + _lingunet(out, True, text_fc) + fusion


#: The reference agent behind each of our agents, and its nets' trainable counts (pick, key, query).
REFERENCE = {
    "transporter_only": ("transporter", _resnet43),
    "two_stream": ("cliport (two_stream_clip_lingunet_lat_transporter)", _two_stream),
    "clip_only": ("clip_lingunet_transporter", lambda out: _lingunet(out, False, False)),
    "rn50_bert": ("two_stream_full_rn50_bert_lingunet_lat_transporter", lambda out: _two_stream(out, True)),
}


def reference_counts(name: str) -> dict[str, object] | None:
    """Trainable parameters of the reference's counterpart of agent ``name``, or None if it has none."""
    if name not in REFERENCE:
        return None
    label, net = REFERENCE[name]
    pick, place = net(1), net(3)
    return {"agent": label, "pick": pick, "key": place, "query": place, "trainable_total": pick + 2 * place}


def agent_counts(name: str) -> dict[str, object]:
    agent = make_agent(name, dict.fromkeys(agent_class(name).weight_sources, "random"))
    nets = {"pick": agent.pick.net, "key": agent.place.key_net, "query": agent.place.query_net}
    out: dict[str, object] = {net: _count(module, trainable=True) for net, module in nets.items()}
    out["trainable_total"] = _count(agent, trainable=True)
    out["frozen"] = _count(agent, trainable=False)
    if agent.weight_sources:
        out["weights"] = "random (counts do not depend on the weights)"
    out["reference"] = reference_counts(name)
    return out


def main() -> None:
    print(json.dumps({name: agent_counts(name) for name in agent_names()}, indent=2))


if __name__ == "__main__":
    main()
