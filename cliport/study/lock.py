"""One driver per study folder: an exclusive ``flock`` on ``OUT/.lock`` for as long as a driver runs.

The kernel drops the lock when the driver's process ends, however it ends, so a crash leaves no stale lock.
On a shared filesystem the lock holds across machines where the filesystem supports ``flock`` (Linux NFS
clients emulate it with byte-range locks).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from typing import Any

from cliport.errors import UserError

LOCK_FILE = ".lock"
#: A status probe holds a shared lock for an instant: a driver retries this long before it refuses.
_RETRY_SECONDS = 2.0


class StudyBusyError(UserError, RuntimeError):
    """Another driver is running the study in this folder."""


def _describe(path: str) -> str:
    try:
        with open(path) as f:
            holder = json.load(f)
        return f"pid {holder['pid']} on {holder['host']}"
    except (OSError, ValueError, KeyError):
        return "another process"


class StudyLock:
    """Hold the study folder's lock (``with StudyLock(out, wait):``). Busy: StudyBusyError, or, with ``wait``,
    wait until the other driver ends."""

    def __init__(self, folder: str, wait: bool = False) -> None:
        self.folder = folder
        self.path = os.path.join(folder, LOCK_FILE)
        self.wait = wait
        self.fd: int | None = None

    def __enter__(self) -> StudyLock:
        os.makedirs(self.folder, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + _RETRY_SECONDS
        told = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if not self.wait and time.monotonic() > deadline:
                    os.close(fd)
                    raise StudyBusyError(
                        f"another cliport-reproduce ({_describe(self.path)}) is running the study in {self.folder}: "
                        "wait for it to end, or pass --wait"
                    ) from None
                if self.wait and not told and time.monotonic() > deadline:
                    print(f"waiting for the other driver ({_describe(self.path)}) of {self.folder}", file=sys.stderr)
                    told = True
                time.sleep(0.2)
        os.ftruncate(fd, 0)
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}
        os.write(fd, json.dumps(holder).encode())
        self.fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self.fd is not None:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def driver_holding(folder: str) -> dict[str, Any] | None:
    """Who holds the folder's lock (pid, host, since), or None when no driver runs the study."""
    path = os.path.join(folder, LOCK_FILE)
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                with open(path) as f:
                    return json.load(f)
            except (OSError, ValueError):
                return {"pid": None, "host": None, "since": None}
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
