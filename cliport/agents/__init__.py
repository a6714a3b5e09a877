"""Pick-and-place agents, found by name through a registry (:mod:`cliport.agents.registry` says what an agent is).

The names below are re-exported from the modules that hold them: the base class (``base``), checkpoint files
(``checkpoint``), the configs (``config``), and the registry with ``make_agent`` and ``load_agent`` (``registry``).
Nothing in this package imports this ``__init__``.
"""

from cliport.agents.base import PickPlaceAgent
from cliport.agents.checkpoint import read_checkpoint, read_weights
from cliport.agents.config import AgentConfig
from cliport.agents.registry import (
    agent_class,
    agent_from_payload,
    agent_names,
    config_classes,
    load_agent,
    make_agent,
    make_config,
    register_agent,
)

__all__ = [
    "AgentConfig",
    "PickPlaceAgent",
    "agent_class",
    "agent_from_payload",
    "agent_names",
    "config_classes",
    "load_agent",
    "make_agent",
    "make_config",
    "read_checkpoint",
    "read_weights",
    "register_agent",
]
