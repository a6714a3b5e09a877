"""The per-process folder for generated URDF and mesh files, removed when the process ends.

PyBullet loads bodies from files, so every :class:`~cliport.env.environment.Environment` writes its
generated assets to disk. All environments of a process share one folder in the temp directory,
``cliport-assets-<pid>-<random>``, created on first use; each environment works in its own subfolder
of it. The folder is removed at interpreter exit (``atexit``), when a multiprocessing worker finishes
(``multiprocessing.util.Finalize``: forked workers leave through ``os._exit``, which skips
``atexit``) and on SIGTERM (turned into ``SystemExit`` where no other handler is installed).
Ownership is keyed by pid: a forked child gets its own folder and never deletes its parent's.
What none of this can catch (SIGKILL, a crash of the interpreter) is swept at the next start: a
folder of this prefix, owned by this user, whose pid no longer runs.
"""

from __future__ import annotations

import atexit
import logging
import os
import re
import shutil
import signal
import tempfile
import threading
from types import FrameType

PREFIX = "cliport-assets-"
_NAME = re.compile(re.escape(PREFIX) + r"(\d+)-[^/]+")

log = logging.getLogger(__name__)

_lock = threading.RLock()  # re-entrant: the SIGTERM handler may run while the main thread holds it
_root: str | None = None
_owner_pid: int | None = None  # the process that created _root (a forked child inherits both)
_finalisers_pid: int | None = None  # the process whose exit hooks are registered


def _reset_lock_in_child() -> None:
    # A fork taken while another thread held the lock would leave it held forever in the child.
    global _lock
    _lock = threading.RLock()


os.register_at_fork(after_in_child=_reset_lock_in_child)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, under another user
        return True
    return True


def sweep_stale(directory: str | None = None) -> list[str]:
    """Remove the asset folders in ``directory`` (the temp dir by default) of this user's dead processes.

    Returns the removed paths. A pid reused by a live process keeps its folder until that one ends.
    """
    directory = directory or tempfile.gettempdir()
    removed: list[str] = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    uid = os.getuid()
    for entry in entries:
        match = _NAME.fullmatch(entry.name)
        if match is None:
            continue
        pid = int(match.group(1))
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not entry.is_dir(follow_symlinks=False) or st.st_uid != uid or pid == os.getpid() or _pid_alive(pid):
            continue
        shutil.rmtree(entry.path, ignore_errors=True)
        if not os.path.exists(entry.path):
            removed.append(entry.path)
    if removed:
        log.debug("removed %d asset folder(s) of ended processes", len(removed))
    return removed


def _cleanup() -> None:
    """Remove this process's folder; a no-op in a forked child that did not create it."""
    global _root, _owner_pid
    with _lock:
        if _root is not None and _owner_pid == os.getpid():
            shutil.rmtree(_root, ignore_errors=True)
            _root, _owner_pid = None, None


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    import multiprocessing

    if _finalisers_pid == os.getpid() and multiprocessing.parent_process() is None:
        raise SystemExit(128 + signum)  # unwinds: finally blocks, context managers and atexit run
    # A multiprocessing child (whose pool would report a SystemExit as a task's result), or a fork
    # that inherited the handler: remove the folder if it is ours, then die by the signal as by default.
    _cleanup()
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


def _install_finalisers() -> None:
    global _finalisers_pid
    if _finalisers_pid == os.getpid():
        return
    _finalisers_pid = os.getpid()
    atexit.register(_cleanup)
    from multiprocessing import util

    util.Finalize(None, _cleanup, exitpriority=0)
    try:
        if signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, _on_sigterm):
            signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread: signal handlers cannot be set here; atexit still runs
        pass


def asset_root() -> str:
    """This process's asset folder, created on first use (sweeping folders of ended processes first)."""
    global _root, _owner_pid
    with _lock:
        if _root is None or _owner_pid != os.getpid() or not os.path.isdir(_root):
            if _owner_pid != os.getpid():
                sweep_stale()
            _root = tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-")
            _owner_pid = os.getpid()
            _install_finalisers()
        return _root


def new_asset_dir(prefix: str = "env-") -> str:
    """A fresh subfolder of this process's asset folder (one per environment, so none collide)."""
    return tempfile.mkdtemp(prefix=prefix, dir=asset_root())


def remove_asset_dir(path: str) -> None:
    """Remove a subfolder made by :func:`new_asset_dir` in this process (never one of a parent's)."""
    with _lock:
        owned = _root is not None and _owner_pid == os.getpid() and os.path.dirname(path) == _root
    if owned:
        shutil.rmtree(path, ignore_errors=True)


__all__ = ["PREFIX", "asset_root", "new_asset_dir", "remove_asset_dir", "sweep_stale"]
