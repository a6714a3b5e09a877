"""The agent registry: the only list of agents in the project, and building agents by name.

:data:`AGENTS` names every agent and its config class. An agent is the class of ``cliport/agents/<name>.py``
decorated with ``@register_agent("<name>")``, a :class:`~cliport.agents.base.PickPlaceAgent` subclass, with its
defaults in ``configs/<name>.toml``. Names, config classes and weight sources come from the table without
importing any agent or torch (the console scripts' flags and ``--help``); an agent's module is imported when its
class is first asked for. Everything that names agents (CLI choices, the reproduction study, scripts, published
numbers) asks :func:`agent_names` and the agent classes' attributes (``uses_language``, ``weight_sources``,
``published_columns``).

An agent is built from a config with :func:`make_agent`, or loaded from a run folder, a weights file or an
``hf://`` name with :meth:`PickPlaceAgent.from_pretrained <cliport.agents.base.PickPlaceAgent.from_pretrained>`.
:func:`agent_class` is the one place a name becomes a class. ``_resolve_agent``, which checks a name and its
settings against the table (no agent imported), is internal; ``TrainConfig.build`` (:mod:`cliport.train.config`)
is the one module outside this one that uses it.
"""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Callable, Mapping
from dataclasses import fields
from typing import TYPE_CHECKING, Any, TypeVar

from cliport.agents.config import AgentConfig, CLIPConfig, RN50BERTConfig
from cliport.errors import ConfigError, UnknownNameError

if TYPE_CHECKING:  # the agents' modules import this one (and torch); they are imported at first use
    from cliport.agents.base import PickPlaceAgent

_PACKAGE = __name__.rpartition(".")[0]

#: Every agent by name, with its config class (the module ``cliport/agents/<name>.py`` defines the agent).
AGENTS: dict[str, type[AgentConfig]] = {
    "clip_only": CLIPConfig,
    "rn50_bert": RN50BERTConfig,
    "transporter_only": AgentConfig,
    "two_stream": CLIPConfig,
}
_REGISTRY: dict[str, type[PickPlaceAgent]] = {}
_Agent = TypeVar("_Agent", bound="PickPlaceAgent")


def register_agent(name: str) -> Callable[[type[_Agent]], type[_Agent]]:
    """Class decorator: make a PickPlaceAgent subclass agent ``name`` of :data:`AGENTS` (its ``name``,
    ``config_class`` and ``weight_sources`` come from there)."""
    if name not in AGENTS:
        raise ValueError(f"agent {name!r} is not in AGENTS (cliport/agents/registry.py): add it with its config class")

    def wrap(cls: type[_Agent]) -> type[_Agent]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"agent name {name!r} is registered twice")
        cls.name = name
        cls.config_class = AGENTS[name]
        cls.weight_sources = AGENTS[name].weight_sources
        _REGISTRY[name] = cls
        return cls

    return wrap


def agent_names() -> list[str]:
    """Every agent name, sorted."""
    return sorted(AGENTS)


def _check_name(name: object) -> str:
    """``name`` if it is an agent's; ConfigError for a value that is no name, UnknownNameError (with the closest
    and the known names) for another name."""
    if not isinstance(name, str):
        raise ConfigError(f"agent must be an agent name, got {name!r}")
    if name not in AGENTS:
        close = difflib.get_close_matches(name, list(AGENTS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UnknownNameError(f"unknown agent {name!r}{hint}; choose one of: {', '.join(agent_names())}")
    return name


def agent_class(name: str) -> type[PickPlaceAgent]:
    """The class of agent ``name`` (its module imported at the first call); UnknownNameError otherwise."""
    _check_name(name)
    if name not in _REGISTRY:
        importlib.import_module(f"{_PACKAGE}.{name}")
        if name not in _REGISTRY:
            raise ValueError(f"{_PACKAGE}.{name} registers no agent {name!r} (@register_agent)")
    return _REGISTRY[name]


def config_classes() -> list[type[AgentConfig]]:
    """The config classes of all agents (each once), for deriving command-line flags; imports no agent."""
    return list(dict.fromkeys(AGENTS[name] for name in agent_names()))


def weight_fields() -> list[str]:
    """The pretrained-weight config fields of all agents (``clip_weights``, ...), each once; imports no agent."""
    return list(dict.fromkeys(f for cls in config_classes() for f in cls.weight_sources))


def _resolve_agent(name: object, overrides: Mapping[str, Any] | None = None) -> type[AgentConfig]:
    """The config class of agent ``name``, once each of ``overrides`` (config fields, any subset) is checked to be
    one of its fields. UnknownNameError for an unknown name; ConfigError naming every setting the agent does not
    have, and its settings. Imports no agent."""
    name = _check_name(name)
    config_class = AGENTS[name]
    known = {f.name for f in fields(config_class)}
    unknown = sorted(set(dict(overrides or {})) - known)
    if unknown:
        close = [difflib.get_close_matches(key, known, n=1) for key in unknown]
        hint = "".join(f" (did you mean {c[0]!r}?)" for c in close if c)
        raise ConfigError(
            f"agent {name} has no setting(s) {', '.join(unknown)}{hint}; its settings: {', '.join(sorted(known))}"
        )
    return config_class


def _make_config(name: str, overrides: Mapping[str, Any] | None = None) -> AgentConfig:
    """The config of agent ``name``: ``configs/<name>.toml`` updated with ``overrides`` (checked)."""
    from cliport.utils.config import load

    config = load(_resolve_agent(name, overrides), name, overrides)
    config.validate()
    return config


def make_agent(name: str, config: AgentConfig | dict[str, Any] | None = None) -> PickPlaceAgent:
    """Build agent ``name`` from its config object, a dict of overrides of its defaults (``configs/<name>.toml``;
    each checked to be a setting of the agent), or the defaults. A trained agent is loaded with
    :meth:`~cliport.agents.base.PickPlaceAgent.from_pretrained` instead."""
    config_class = _resolve_agent(name, config if isinstance(config, dict) else None)
    if not isinstance(config, config_class):
        if config is not None and not isinstance(config, dict):
            raise TypeError(f"{name} needs a {config_class.__name__} or a dict, got {type(config).__name__}")
        config = _make_config(name, config)
    return agent_class(name)(config)  # type: ignore[call-arg]  # registered agents take (config); the base takes nets


__all__ = [
    "AGENTS",
    "agent_class",
    "agent_names",
    "config_classes",
    "make_agent",
    "register_agent",
    "weight_fields",
]
