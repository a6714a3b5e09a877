"""The agent registry: the only list of agents in the project, found by name, and building agents by name.

An agent is one module in this package that defines a :class:`~cliport.agents.base.PickPlaceAgent` subclass
decorated with ``@register_agent("name", ConfigClass)``, and its defaults in ``configs/<name>.toml``. Everything
that names agents (CLI choices, the reproduction study, scripts, published numbers) asks :func:`agent_names`
and the agent classes' attributes (``uses_language``, ``weight_sources``, ``published_columns``).
"""

from __future__ import annotations

import difflib
import importlib
import os
import pkgutil
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import torch

from cliport.agents.checkpoint import read_checkpoint
from cliport.agents.config import AgentConfig
from cliport.errors import CheckpointError, ConfigError, UnknownNameError

if TYPE_CHECKING:  # base.py imports this module (from_pretrained builds agents by name)
    from cliport.agents.base import PickPlaceAgent

_PACKAGE = __name__.rpartition(".")[0]
_REGISTRY: dict[str, type[PickPlaceAgent]] = {}
_NOT_AGENTS = {"base", "checkpoint", "config", "decode", "device_options", "loss", "registry"}
_discovered = False
_Agent = TypeVar("_Agent", bound="PickPlaceAgent")


def register_agent(name: str, config: type[AgentConfig]) -> Callable[[type[_Agent]], type[_Agent]]:
    """Class decorator: make a PickPlaceAgent subclass buildable as ``make_agent(name)``."""

    def wrap(cls: type[_Agent]) -> type[_Agent]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"agent name {name!r} is registered twice")
        cls.name = name
        cls.config_class = config
        _REGISTRY[name] = cls
        return cls

    return wrap


def _discover() -> None:
    global _discovered
    if not _discovered:
        for info in pkgutil.iter_modules([os.path.dirname(__file__)]):
            if info.name not in _NOT_AGENTS and not info.name.startswith("_"):
                importlib.import_module(f"{_PACKAGE}.{info.name}")
        _discovered = True


def agent_names() -> list[str]:
    """Every registered agent name, sorted."""
    _discover()
    return sorted(_REGISTRY)


def agent_class(name: str) -> type[PickPlaceAgent]:
    """The class registered as ``name``; UnknownNameError (with the known names) otherwise."""
    _discover()
    if name not in _REGISTRY:
        close = difflib.get_close_matches(name, list(_REGISTRY), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UnknownNameError(f"unknown agent {name!r}{hint}; choose one of: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def config_classes() -> list[type[AgentConfig]]:
    """The config classes of all agents (each once), for deriving command-line flags."""
    out: list[type[AgentConfig]] = []
    for name in agent_names():
        cls = _REGISTRY[name].config_class
        if cls not in out:
            out.append(cls)
    return out


def make_config(name: str, overrides: dict[str, Any] | None = None) -> AgentConfig:
    """The config of agent ``name``: ``configs/<name>.toml`` updated with ``overrides`` (checked)."""
    from cliport.utils.config import load

    config = load(agent_class(name).config_class, name, overrides)
    config.validate()
    return config


def make_agent(name: str, config: AgentConfig | dict[str, Any] | None = None) -> PickPlaceAgent:
    """Build agent ``name`` from a config object, a dict of overrides of the defaults, or the defaults."""
    cls = agent_class(name)
    if not isinstance(config, cls.config_class):
        if config is not None and not isinstance(config, dict):
            raise TypeError(f"{name} needs a {cls.config_class.__name__} or a dict, got {type(config).__name__}")
        config = make_config(name, config)
    return cls(config)  # type: ignore[call-arg]  # registered agents take (config); the base class takes nets


def agent_from_payload(
    payload: dict[str, Any],
    path: str | os.PathLike[str],
    device: str | torch.device = "cpu",
    weights: dict[str, str] | None = None,
) -> PickPlaceAgent:
    """Build the agent a checkpoint payload (``read_checkpoint`` or ``read_weights``) describes and load its
    weights; ``weights`` overrides recorded pretrained sources (see :func:`load_agent`). ``path`` names the
    file in errors."""
    cls = agent_class(payload["agent"])
    config = dict(payload["config"])
    overrides = dict(weights or {})
    for field in cls.weight_sources:
        recorded = payload.get("weight_sources", {}).get(field) or payload.get(field)
        config[field] = overrides.get(field) or recorded or config.get(field)
    try:
        agent = make_agent(payload["agent"], config)
    except ConfigError as e:
        raise CheckpointError(f"{path}: {e}") from e
    try:
        agent.load_trainable_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError) as e:
        raise CheckpointError(f"{path} does not match its recorded agent config: {e}") from e
    return agent.to(device)


def load_agent(
    path: str | os.PathLike[str],
    device: str | torch.device = "cpu",
    weights: dict[str, str] | None = None,
    clip_weights: str | None = None,
) -> PickPlaceAgent:
    """Rebuild an agent from a checkpoint written by ``save_checkpoint``.

    Pretrained parts are reloaded from the sources the checkpoint records unless ``weights`` maps a
    source field (e.g. ``{"clip_weights": "/other/path/RN50.pt"}``) to another one; a field the agent
    does not have is ignored. ``clip_weights`` is shorthand for that field.
    """
    overrides = dict(weights or {})
    if clip_weights is not None:
        overrides["clip_weights"] = clip_weights
    return agent_from_payload(read_checkpoint(path), path, device, overrides)


__all__ = [
    "agent_class",
    "agent_from_payload",
    "agent_names",
    "config_classes",
    "load_agent",
    "make_agent",
    "make_config",
    "register_agent",
]
