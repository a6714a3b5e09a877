"""Pick-and-place agents, found by name through a registry (:mod:`cliport.agents.registry` says what an agent is).

An agent is built from a config with ``make_agent(name, config_or_overrides)`` or loaded from a run folder, a weights
file or an ``hf://`` name with ``PickPlaceAgent.from_pretrained(source)``; ``agent_class(name)`` is its class.
The names below are re-exported from the modules that hold them: the base class (``base``), checkpoint files
(``checkpoint``), the configs (``config``), and the registry (``registry``).
Each is imported when first used, so that importing a module of this package (the registry, the configs: what the
console scripts' flags need) loads no agent and no torch. Nothing in this package imports this ``__init__``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cliport.agents.base import PickPlaceAgent
    from cliport.agents.checkpoint import read_checkpoint, read_weights
    from cliport.agents.config import AgentConfig
    from cliport.agents.registry import agent_class, agent_names, config_classes, make_agent, register_agent

__all__ = [
    "AgentConfig",
    "PickPlaceAgent",
    "agent_class",
    "agent_names",
    "config_classes",
    "make_agent",
    "read_checkpoint",
    "read_weights",
    "register_agent",
]

#: The module of this package that holds each re-exported name (the registry, unless named here).
_HOMES = {
    **dict.fromkeys(__all__, "registry"),
    "PickPlaceAgent": "base",
    "read_checkpoint": "checkpoint",
    "read_weights": "checkpoint",
    "AgentConfig": "config",
}


def __getattr__(name: str) -> Any:
    """A re-exported name, imported from its module at first use and kept here (so it can be monkeypatched)."""
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    globals()[name] = value
    return value
