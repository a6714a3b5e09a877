"""Print JSON with the trainable and frozen parameter counts of both agents at their real sizes.

CLIP is random-initialised here (counts do not depend on the weights), so no download is needed.
"""

from __future__ import annotations

import json

from torch import nn

from cliport.agents import make_agent


def _count(module: nn.Module, trainable: bool) -> int:
    return sum(p.numel() for p in module.parameters() if p.requires_grad == trainable)


def agent_counts(name: str) -> dict[str, object]:
    agent = make_agent(name, {"clip_weights": "random"} if name == "two_stream" else None)
    nets = {"pick": agent.pick.net, "key": agent.place.key_net, "query": agent.place.query_net}
    out: dict[str, object] = {net: _count(module, trainable=True) for net, module in nets.items()}
    out["trainable_total"] = _count(agent, trainable=True)
    out["frozen_clip"] = 0 if agent.clip is None else _count(agent.clip, trainable=False)
    if agent.clip is not None:
        out["clip_weights"] = "random (counts do not depend on the weights)"
    return out


def main() -> None:
    print(json.dumps({name: agent_counts(name) for name in ("transporter_only", "two_stream")}, indent=2))


if __name__ == "__main__":
    main()
