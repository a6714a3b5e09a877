"""The one config mechanism: plain (nested) dataclasses, defaults in ``configs/*.toml``, flags from fields.

- Each config class documents its fields under ``Args:`` in its docstring; that text is the flag's help.
- :func:`from_dict` builds a (nested) config from a mapping, rejecting unknown, missing and mistyped keys
  with a :class:`~cliport.errors.ConfigError` that names the source (a file, "flags", ...) and the key.
- :func:`add_flags` derives argparse options from the fields (``n_demos`` -> ``--n-demos``) and
  :func:`given_flags` reads back only what the user gave, as a nested dict of overrides.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from functools import cache
from importlib import resources
from typing import Any, TypeVar

from cliport.errors import ConfigError

T = TypeVar("T")


def defaults_file(name: str) -> str:
    """Where ``configs/<name>.toml`` lives (shipped as package data of ``cliport.configs``)."""
    return str(resources.files("cliport.configs").joinpath(f"{name}.toml"))


def read_defaults(name: str) -> dict[str, Any]:
    """The table in ``configs/<name>.toml``."""
    path = resources.files("cliport.configs").joinpath(f"{name}.toml")
    if not path.is_file():
        raise ConfigError(f"no default config named {name!r} (looked for {path})")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: {e}") from e


def device_defaults(name: str, device: str, section: str | None = None) -> dict[str, Any]:
    """The table in ``configs/<name>.toml`` (or its ``section``) with the values of its ``device`` table (``cpu``,
    ``cuda``) over its own: ``[language.cpu]`` of ``quickstart.toml`` overrides ``[language]`` on a CPU."""
    table = read_defaults(name)
    if section is not None:
        table = table[section]
    if device not in table:
        raise ConfigError(f"configs/{name}.toml has no [{'.'.join(filter(None, (section, device)))}] table")
    return {**table, **table[device]}


@cache
def field_docs(cls: type) -> dict[str, str]:
    """``{field: description}`` from the ``Args:`` section of a class docstring (inherited ones too)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        text = klass.__dict__.get("__doc__") or ""
        if "Args:" not in text:
            continue
        current = None
        for line in text.split("Args:", 1)[1].splitlines():
            match = re.match(r"\s{4,}(\w+):\s*(.*)", line)
            if match and match.group(1) in {f.name for f in dataclasses.fields(cls)}:
                current = match.group(1)
                docs[current] = match.group(2).strip()
            elif current and line.strip() and re.match(r"\s{6,}", line):
                docs[current] += " " + line.strip()
            elif not line.strip():
                current = None
    return docs


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_config(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _check(value: Any, tp: Any, where: str) -> Any:
    """``value`` converted to type ``tp`` where that is lossless (int -> float), else a ConfigError."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(tp)
        if value is None and type(None) in options:
            return None
        errors = []
        for option in options:
            if option is type(None):
                continue
            try:
                return _check(value, option, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(errors[0] if errors else f"{where} must not be None")
    if origin is list:
        (item,) = typing.get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where} must be a list of {_type_name(item)}, got {value!r}")
        return [_check(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where} must be a table, got {value!r}")
        return dict(value)
    if tp is Any:
        return value
    if tp is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if tp in (int, float) and isinstance(value, bool):
        raise ConfigError(f"{where} must be {_type_name(tp)}, got {value!r}")
    if not isinstance(value, tp):
        raise ConfigError(f"{where} must be {_type_name(tp)}, got {value!r}")
    return value


def from_dict(cls: type[T], data: Mapping[str, Any], source: str, nested: Mapping[str, type] | None = None) -> T:
    """Build dataclass ``cls`` from ``data``; nested config fields take nested tables.

    ``nested`` names a subclass to build for a nested field whose class depends on another setting
    (the agent's config class, say). Unknown, missing or mistyped keys raise ConfigError naming
    ``source`` and the key path.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a table for {cls.__name__}, got {data!r}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]  # T: a dataclass
    unknown = sorted(set(data) - set(fields))
    if unknown:
        close = {k: _closest(k, fields) for k in unknown}
        hint = "".join(f" (did you mean {c!r}?)" for c in close.values() if c)
        raise ConfigError(f"{source}: unknown {cls.__name__} key(s) {', '.join(map(repr, unknown))}{hint}")
    values = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{source}: missing {cls.__name__} key {name!r}")
            continue
        tp = (nested or {}).get(name, hints[name])
        if _is_config(tp):
            values[name] = from_dict(tp, data[name], f"{source} [{name}]")
        else:
            values[name] = _check(data[name], tp, f"{source}: {name}")
    return cls(**values)


def _closest(key: str, names: Iterable[str]) -> str | None:
    import difflib

    found = difflib.get_close_matches(key, list(names), n=1)
    return found[0] if found else None


def merge(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated with ``overrides``, nested tables merged key by key."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def load(cls: type[T], name: str, overrides: Mapping[str, Any] | None = None) -> T:
    """``cls`` from ``configs/<name>.toml`` updated with ``overrides`` (checked like the file)."""
    data = read_defaults(name)
    from_dict(cls, data, defaults_file(name))  # the file alone must be valid, so its errors name it
    return from_dict(cls, merge(data, overrides or {}), f"{defaults_file(name)} + overrides")


def defaults(cls: type[T], name: str, **overrides: Any) -> T:
    """``cls`` from ``configs/<name>.toml`` with the keyword overrides that are not None."""
    return load(cls, name, {k: v for k, v in overrides.items() if v is not None})


def to_dict(config: Any) -> dict[str, Any]:
    """A resolved config as a plain nested dict, for saving next to a run's outputs."""
    return dataclasses.asdict(config)


# ------------------------------------------------------------------ command-line flags
def _flag_spec(tp: Any) -> dict[str, Any]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = [t for t in typing.get_args(tp) if t is not type(None)]
        return _flag_spec(options[0])
    if origin is list:
        (item,) = typing.get_args(tp)
        return {"nargs": "+", "type": item}
    if tp is bool:
        return {"action": argparse.BooleanOptionalAction}
    if tp in (int, float, str):
        return {"type": tp}
    raise TypeError(f"no command-line flag for a field of type {tp}")


def add_flags(
    parser: argparse.ArgumentParser | Any,
    classes: Iterable[type],
    section: str | None = None,
    skip: Iterable[str] = (),
    taken: set[str] | None = None,
    only: Iterable[str] | None = None,
    extra: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[str]:
    """Add ``--field-name`` options for the scalar and list fields of ``classes`` (merged by name).

    The values land under ``dest = "section.field"`` (or ``"field"``); every default is None so that
    :func:`given_flags` sees only what was typed. Returns the dests added. ``taken`` collects the
    flag names across calls; a name added twice is a programming error. ``only``: add just these fields
    (and not ``skip``'s). ``extra``: per field, ``add_argument`` keywords over the derived ones (``choices``, or
    the ``help`` of a command whose use of the field differs from its description).
    """
    taken = set() if taken is None else taken
    classes = list(classes)
    wanted = None if only is None else set(only)
    unknown = (wanted or set()) - {f.name for cls in classes for f in dataclasses.fields(cls)}
    if unknown:
        raise ValueError(f"no field named {', '.join(sorted(unknown))} in {', '.join(c.__name__ for c in classes)}")
    extra = extra or {}
    dests: list[str] = []
    seen: dict[str, Any] = {}
    for cls in classes:
        hints = _hints(cls)
        docs = field_docs(cls)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            if f.name in skip or f.name in seen or _is_config(tp) or typing.get_origin(tp) is dict or tp is dict:
                continue
            if wanted is not None and f.name not in wanted:
                continue
            seen[f.name] = tp
            flag = "--" + f.name.replace("_", "-")
            if flag in taken:
                raise ValueError(f"flag {flag} is derived from two config fields")
            taken.add(flag)
            dest = f"{section}.{f.name}" if section else f.name
            help_text = docs.get(f.name, "")
            owners = [c.__name__ for c in classes if f.name in {x.name for x in dataclasses.fields(c)}]
            if len(owners) < len(classes):
                help_text += f" (only {', '.join(owners)})"
            spec = _flag_spec(tp)
            if "action" not in spec and "choices" not in extra.get(f.name, {}):
                spec["metavar"] = f.name.upper()
            spec = {"help": help_text or None, **spec, **extra.get(f.name, {})}
            parser.add_argument(flag, dest=dest, default=None, **spec)
            dests.append(dest)
    return dests


def given_flags(args: argparse.Namespace, dests: Iterable[str]) -> dict[str, Any]:
    """The values of ``dests`` the user gave, as a nested dict (``"env.camera_scale"`` -> env table)."""
    out: dict[str, Any] = {}
    for dest in dests:
        value = getattr(args, dest, None)
        if value is None:
            continue
        *sections, key = dest.split(".")
        table = out
        for s in sections:
            table = table.setdefault(s, {})
        table[key] = value
    return out
