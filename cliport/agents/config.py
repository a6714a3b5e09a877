"""Agent configurations: plain dataclasses whose defaults live in ``configs/<agent>.toml``."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from importlib.resources import files
from typing import Any, Self


def _toml_defaults(name: str) -> dict[str, Any]:
    return tomllib.loads(files("cliport.configs").joinpath(f"{name}.toml").read_text(encoding="utf-8"))


@dataclass
class TransporterOnlyConfig:
    """Transporter Networks agent.

    n_rotations: place rotation bins (bin k = relative yaw k * 2*pi / n_rotations).
    crop_size: side of the query crop around the pick pixel (even).
    lr: Adam learning rate.
    width: channel-width multiplier of the nets; 1.0 is the published size, small values make tiny test nets.
    """

    n_rotations: int
    crop_size: int
    lr: float
    width: float

    toml_name = "transporter_only"

    @classmethod
    def from_dict(cls, overrides: dict[str, Any] | None = None) -> Self:
        """The TOML defaults updated with `overrides`; unknown keys are an error."""
        values = _toml_defaults(cls.toml_name)
        values.update(overrides or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(values) - names
        if unknown:
            raise ValueError(f"unknown {cls.toml_name} config keys: {sorted(unknown)}")
        missing = names - set(values)
        if missing:
            raise ValueError(f"missing {cls.toml_name} config keys: {sorted(missing)}")
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the fields (what checkpoints store)."""
        return dataclasses.asdict(self)


@dataclass
class TwoStreamConfig(TransporterOnlyConfig):
    """CLIPort two-stream agent; as :class:`TransporterOnlyConfig` plus

    clip_weights: "openai", a path to local RN50 weights, or "random" (seeded; tests and benchmarks).
    """

    clip_weights: str

    toml_name = "two_stream"
