"""Shared pieces of the console scripts: one clear line and exit status 2 for the user's errors, ``--version``.

Only the project's own user-error exceptions (:class:`cliport.errors.UserError` and its subclasses) are
turned into ``error: <message>``; anything else is a bug and keeps its traceback. Every parser built as a
:class:`OneLineParser` answers ``--version`` with :func:`version_line`.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tomllib
from collections.abc import Callable
from typing import Any, NoReturn

from cliport import __version__
from cliport.errors import ConfigError, UserError

__all__ = [
    "OneLineParser",
    "UserError",
    "add_weight_flags",
    "fail",
    "parse_key_values",
    "run_cli",
    "version_line",
    "weight_overrides",
]


def fail(message: str, code: int = 2) -> NoReturn:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(code)


def run_cli(main: Callable[[], None]) -> None:
    """Run ``main``; a UserError becomes ``error: <message>`` on stderr and exit status 2."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        main()
    except UserError as e:
        fail(str(e))
    except KeyboardInterrupt:
        fail("interrupted; finished work is kept and a re-run resumes", code=130)


def parse_key_values(items: list[str], flag: str) -> dict[str, Any]:
    """``["n_rotations=12", "clip_weights=random"]`` -> ``{"n_rotations": 12, "clip_weights": "random"}``
    (values read as TOML where they parse, else as strings)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{flag} must look like KEY=VALUE, got {item!r}")
        try:
            out[key] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = value
    return out


def version_line() -> str:
    """What ``--version`` prints: ``cliport 0.3.0`` (the installed distribution's version)."""
    return f"cliport {__version__}"


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are the project's one ``error:`` line (no usage block), exit 2, and that
    answers ``--version`` (:func:`version_line` on stdout, exit 0)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.add_argument("--version", action="version", version=version_line(), help="print the version and exit")

    def error(self, message: str) -> NoReturn:
        fail(f"{self.prog}: {message} (see {self.prog} --help)")


def weight_fields() -> list[str]:
    """The pretrained-weight config fields of all agents (``clip_weights``, ...), each once (no agent imported)."""
    from cliport.agents.registry import weight_fields as fields

    return fields()


def add_weight_flags(parser: argparse.ArgumentParser) -> None:
    """One flag per field of :func:`weight_fields` (``--clip-weights``, ...), to load that pretrained part
    from another source than the one a checkpoint records."""
    for field in weight_fields():
        part = field.removesuffix("_weights").upper()
        flag = "--" + field.replace("_", "-")
        parser.add_argument(flag, help=f"load the {part} weights from here instead of the source the run recorded")


def weight_overrides(args: argparse.Namespace) -> dict[str, str] | None:
    """``{field: source}`` of the weight flags given (see :func:`add_weight_flags`), or None."""
    given = {field: getattr(args, field) for field in weight_fields() if getattr(args, field, None)}
    return given or None
