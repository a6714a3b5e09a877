"""Agents by name: ``make_agent("two_stream" | "transporter_only", config)`` and ``load_agent(path)``."""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Any

import torch

from cliport.agents.base import PickPlaceAgent
from cliport.agents.config import TransporterOnlyConfig, TwoStreamConfig


@dataclass(frozen=True)
class AgentSpec:
    """Where an agent class lives (imported lazily) and its config class."""

    module: str
    cls: str
    config: type[TransporterOnlyConfig]


AGENTS: dict[str, AgentSpec] = {
    "transporter_only": AgentSpec("cliport.agents.transporter_only", "TransporterOnlyAgent", TransporterOnlyConfig),
    "two_stream": AgentSpec("cliport.agents.two_stream", "TwoStreamAgent", TwoStreamConfig),
}


def make_config(name: str, overrides: dict[str, Any] | None = None) -> TransporterOnlyConfig:
    """The config of agent `name`: TOML defaults updated with `overrides`."""
    return _spec(name).config.from_dict(overrides)


def make_agent(name: str, config: TransporterOnlyConfig | dict[str, Any] | None = None) -> PickPlaceAgent:
    """Build agent `name` from a config object, a dict of overrides of the defaults, or the defaults."""
    spec = _spec(name)
    if not isinstance(config, spec.config):
        if config is not None and not isinstance(config, dict):
            raise TypeError(f"{name} needs a {spec.config.__name__} or a dict, got {type(config).__name__}")
        config = spec.config.from_dict(config)
    agent_cls = getattr(importlib.import_module(spec.module), spec.cls)
    return agent_cls(config)


def load_agent(
    path: str | os.PathLike[str], device: str | torch.device = "cpu", clip_weights: str | None = None
) -> PickPlaceAgent:
    """Rebuild an agent from a checkpoint written by ``save_checkpoint``.

    CLIP is reloaded from the recorded source unless `clip_weights` names another one (e.g. the same
    weights at a different path on this machine).
    """
    payload = torch.load(path, map_location="cpu", weights_only=True)
    config = dict(payload["config"])
    if "clip_weights" in config:  # agents without CLIP ignore a clip_weights override
        config["clip_weights"] = clip_weights or payload.get("clip_weights") or config["clip_weights"]
    agent = make_agent(payload["agent"], config)
    agent.load_trainable_state_dict(payload["state_dict"])
    return agent.to(device)


def _spec(name: str) -> AgentSpec:
    if name not in AGENTS:
        raise KeyError(f"unknown agent {name!r}; known: {sorted(AGENTS)}")
    return AGENTS[name]


__all__ = ["AGENTS", "PickPlaceAgent", "load_agent", "make_agent", "make_config"]
