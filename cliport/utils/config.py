"""Plain-dataclass configs whose defaults live in TOML files under ``configs/``."""

from __future__ import annotations

import dataclasses
import tomllib
from importlib import resources
from typing import Any, TypeVar

T = TypeVar("T")


def read_defaults(name: str) -> dict[str, Any]:
    """The table in ``configs/<name>.toml`` (shipped as package data of ``cliport.configs``)."""
    path = resources.files("cliport.configs").joinpath(f"{name}.toml")
    if not path.is_file():
        raise FileNotFoundError(f"no default config named {name!r} (looked for {path})")
    return tomllib.loads(path.read_text())


def build(cls: type[T], defaults: dict[str, Any], **overrides: Any) -> T:
    """Instantiate dataclass ``cls`` from ``defaults`` updated with the non-None ``overrides``.

    Unknown keys are an error naming the key, so a typo in a TOML file or a flag never goes unnoticed.
    """
    fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    values = dict(defaults)
    values.update({k: v for k, v in overrides.items() if v is not None})
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} setting(s): {', '.join(unknown)}")
    return cls(**values)


def to_dict(config: Any) -> dict[str, Any]:
    """A resolved config as a plain dict (tuples become lists) for saving next to a run's outputs."""
    return dataclasses.asdict(config)
