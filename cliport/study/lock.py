"""Exclusive ``flock`` locks on files in a study folder: ``OUT/.lock`` while a driver runs the study (one driver
per folder), and ``cells/NAME/.lock`` while an attempt runs a cell (one attempt per cell at a time).

The kernel drops a lock when its process ends, however it ends, so a crash leaves no stale lock. On a shared
filesystem the locks hold across machines where the filesystem supports ``flock`` (Linux NFS clients emulate
it with byte-range locks). The lock file holds the holder's pid, host and start time, for messages.
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

STUDY_LOCK = ".lock"
#: A status probe holds a shared lock for an instant: a driver retries this long before it refuses.
_RETRY_SECONDS = 2.0


class StudyBusyError(UserError, RuntimeError):
    """Another driver is running the study in this folder."""


def _describe(holder: dict[str, Any] | None) -> str:
    if not holder or not holder.get("pid"):
        return "another process"
    return f"pid {holder['pid']} on {holder['host']}"


def _read_holder(path: str) -> dict[str, Any] | None:
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


class FileLock:
    """Hold an exclusive lock on ``path`` (``with FileLock(path):``). Held elsewhere: ``busy(holder)`` (a
    UserError) is raised after a short retry, or, with ``wait``, the lock is waited for (``waiting`` printed)."""

    def __init__(self, path: str, wait: bool = False, busy: Any = None, waiting: str = "") -> None:
        self.path = path
        self.wait = wait
        self.busy = busy
        self.waiting = waiting
        self.fd: int | None = None

    def __enter__(self) -> FileLock:
        os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + _RETRY_SECONDS
        told = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                late = time.monotonic() > deadline
                if late and not self.wait:
                    os.close(fd)
                    raise self.busy(_describe(_read_holder(self.path))) from None
                if late and self.waiting and not told:
                    print(f"{self.waiting} ({_describe(_read_holder(self.path))})", file=sys.stderr, flush=True)
                    told = True
                time.sleep(0.2)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}).encode())
        self.fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self.fd is not None:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def study_lock(folder: str, wait: bool = False) -> FileLock:
    """The study folder's driver lock: a second driver refuses (StudyBusyError), or waits with ``wait``."""

    def busy(holder: str) -> StudyBusyError:
        return StudyBusyError(
            f"another cliport-reproduce ({holder}) is running the study in {folder}: wait for it to end, or pass --wait"
        )

    waiting = f"waiting for the other driver of {folder} to end"
    return FileLock(os.path.join(folder, STUDY_LOCK), wait=wait, busy=busy, waiting=waiting)


def lock_holder(path: str) -> dict[str, Any] | None:
    """Who holds the lock on ``path`` (pid, host, since), or None when nobody does."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_holder(path) or {"pid": None, "host": None, "since": None}
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def driver_holding(folder: str) -> dict[str, Any] | None:
    """The driver running the study in ``folder`` (pid, host, since), or None."""
    return lock_holder(os.path.join(folder, STUDY_LOCK))
