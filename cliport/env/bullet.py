"""PyBullet, imported in one place, at its first use, with its build-time banner kept off the console.

``import pybullet`` prints ``pybullet build time: ...`` from C on file descriptor 2 at every start of
a process. Library modules import it from here (``from cliport.env.bullet import p``) so that the
first import happens with the native stdout/stderr silenced. ``p`` imports PyBullet when one of its
names is first read: the task registry (names, expert settings) and training from demos work where
PyBullet is missing or still being built.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from types import ModuleType
from typing import Any


@contextlib.contextmanager
def quiet_native_output() -> Iterator[None]:
    """Silence C-level writes to stdout and stderr (file descriptors 1 and 2) inside the block."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # descriptors already closed (a daemon): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        # One restore per finally: a Ctrl-C (KeyboardInterrupt) raised right after the first must not leave
        # stderr on /dev/null, where its traceback and everything after it would vanish.
        try:
            os.dup2(saved[0], 1)
        finally:
            try:
                os.dup2(saved[1], 2)
            finally:
                for fd in (*saved, devnull):
                    os.close(fd)


def _import_pybullet() -> ModuleType:
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with quiet_native_output():
        import pybullet
    return pybullet


class _PyBullet(ModuleType):
    """Stands for the ``pybullet`` module; the first attribute read imports it and copies its names here, so
    later reads are plain attribute lookups."""

    def __getattr__(self, name: str) -> Any:
        module = _import_pybullet()
        self.__dict__.update({k: v for k, v in vars(module).items() if k not in ("__name__", "__doc__")})
        return getattr(module, name)


p: Any = _PyBullet("pybullet")

__all__ = ["p", "quiet_native_output"]
