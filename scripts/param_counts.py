"""Print JSON with the trainable and frozen parameter counts of every registered agent at its real size.

Pretrained parts are random-initialised here (counts do not depend on the weights), so no download is needed.
"""

from __future__ import annotations

import json

from torch import nn

from cliport.agents import agent_class, agent_names, make_agent


def _count(module: nn.Module, trainable: bool) -> int:
    return sum(p.numel() for p in module.parameters() if p.requires_grad == trainable)


def agent_counts(name: str) -> dict[str, object]:
    agent = make_agent(name, dict.fromkeys(agent_class(name).weight_sources, "random"))
    nets = {"pick": agent.pick.net, "key": agent.place.key_net, "query": agent.place.query_net}
    out: dict[str, object] = {net: _count(module, trainable=True) for net, module in nets.items()}
    out["trainable_total"] = _count(agent, trainable=True)
    out["frozen"] = _count(agent, trainable=False)
    if agent.weight_sources:
        out["weights"] = "random (counts do not depend on the weights)"
    return out


def main() -> None:
    print(json.dumps({name: agent_counts(name) for name in agent_names()}, indent=2))


if __name__ == "__main__":
    main()
