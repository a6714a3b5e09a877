"""Atomic writes (temp file in the same folder + rename) and checked reads of JSON and torch files.

A reader never sees a half-written file: an interrupted write leaves the previous version (or none).
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from cliport.errors import CheckpointError, UserError


def _atomic_write(path: str | os.PathLike[str], write: Callable[[IO[bytes]], object]) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Write ``data`` as indented JSON, atomically."""
    text = json.dumps(data, indent=2).encode()
    _atomic_write(path, lambda f: f.write(text))


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data``, atomically."""
    _atomic_write(path, lambda f: f.write(data))


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8), atomically."""
    write_bytes(path, text.encode())


def read_json(path: str | os.PathLike[str], error: type[UserError] | None = None, missing: str | None = None) -> Any:
    """The value a JSON file holds. With ``error`` (a user-error class), a missing file raises ``error(missing)``
    (default: ``PATH not found``) and a file that is not JSON ``error("PATH is not valid JSON: ...")``; without it,
    the OS's and the JSON decoder's own exceptions."""
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        if error is None:
            raise
        raise error(missing or f"{path} not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        if error is None:
            raise
        raise error(f"{path} is not valid JSON: {e}") from None


def save_torch(obj: Any, path: str | os.PathLike[str]) -> None:
    """``torch.save`` to ``path``, atomically."""
    import torch

    _atomic_write(path, lambda f: torch.save(obj, f))


def load_torch(path: str | os.PathLike[str], weights_only: bool = True) -> Any:
    """``torch.load`` on the CPU; a missing, truncated or foreign file raises CheckpointError naming it."""
    import torch

    if not os.path.isfile(path):
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=weights_only)
    except (
        RuntimeError, EOFError, zipfile.BadZipFile, pickle.UnpicklingError, ValueError, OSError,
        # what the weights-only unpickler raises on random bytes besides UnpicklingError (~10% of files)
        IndexError, KeyError, UnicodeDecodeError,
    ) as e:  # fmt: skip
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        if "weights_only" in first or "Weights only load failed" in str(e):
            first = "it holds objects that a cliport checkpoint never holds"
        raise CheckpointError(f"cannot read checkpoint {path} (truncated or not a cliport checkpoint): {first}") from e


def _atomic_write_path(path: str | os.PathLike[str], write: Callable[[str], None]) -> None:
    """Like :func:`_atomic_write` for writers that take a file name rather than an open file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_safetensors(tensors: dict[str, Any], path: str | os.PathLike[str], metadata: dict[str, str]) -> None:
    """Write CPU tensors and string metadata as a safetensors file (no pickle), atomically."""
    from safetensors.torch import save_file

    tensors = {k: v.detach().cpu().contiguous() for k, v in tensors.items()}
    _atomic_write_path(path, lambda tmp: save_file(tensors, tmp, metadata=metadata))


def load_safetensors(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, str]]:
    """(tensors on the CPU, string metadata) of a safetensors file; CheckpointError naming a missing,
    truncated or foreign file. Nothing is unpickled."""
    from safetensors import SafetensorError, safe_open

    if not os.path.isfile(path):
        raise CheckpointError(f"weights file not found: {path}")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            metadata = dict(f.metadata() or {})
            tensors = {key: f.get_tensor(key) for key in f.keys()}
    except (SafetensorError, OSError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"cannot read weights file {path} (truncated or not a safetensors file): {first}") from e
    return tensors, metadata


def link_or_copy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Make ``dst`` a hard link to ``src`` (a copy where links are not supported), replacing it atomically."""
    dst = Path(dst)
    fd, tmp = tempfile.mkstemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".tmp")
    os.close(fd)
    os.unlink(tmp)
    try:
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
