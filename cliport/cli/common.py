"""Shared pieces of the console scripts: one clear line and a non-zero exit for user errors."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import NoReturn


class UserError(Exception):
    """A problem with the user's input (flags, paths, data): reported as one line, no traceback."""


def fail(message: str, code: int = 2) -> NoReturn:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(code)


def run_cli(main: Callable[[], None], user_errors: tuple[type[BaseException], ...] = ()) -> None:
    """Run ``main``; user errors become ``error: <message>`` on stderr and exit status 2."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        main()
    except (UserError, *user_errors) as e:
        message = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        fail(str(message))
    except KeyboardInterrupt:
        fail("interrupted; finished work is kept and a re-run resumes", code=130)
