"""Reading pickles from other people without running their code.

A pickle may name any importable function and call it while loading (``os.system``, ``builtins.eval``,
...). :class:`RestrictedUnpickler` resolves a global name only from an explicit table of real objects
(functions that build plain data); names under a few data-only namespaces (configuration objects,
typing markers) become :class:`InertObject` placeholders that record what the pickle gave them and never
run anything; every other name is refused with :class:`UnsafePickleError` before it could be called.
:func:`load_torch_checkpoint` reads a ``torch.save`` zip archive this way, rebuilding tensors from the
archive's raw storages itself (``torch.load`` is never called on such a file).
"""

from __future__ import annotations

import _compat_pickle
import builtins
import io
import pickle
import zipfile
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any

import torch

from cliport.errors import UserError


class UnsafePickleError(UserError, ValueError):
    """The pickle names a global that is neither plain data nor a known data-only class (``global_name``)."""

    def __init__(self, message: str, global_name: str | None = None) -> None:
        super().__init__(message)
        self.global_name = global_name


class UnreadablePickleError(UserError, ValueError):
    """The file is not a readable pickle / torch archive (truncated, corrupt or another format)."""


class InertObject:
    """What an object of a class we do not load becomes: its global name and what the pickle passed it
    (constructor arguments, state, list items, dict items); no method of the real class ever runs."""

    global_name = "?"
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    state: Any
    items: list[Any]
    entries: dict[Any, Any]

    def __new__(cls, *args: Any, **kwargs: Any) -> InertObject:  # NEWOBJ calls only __new__
        obj = super().__new__(cls)
        obj.args, obj.kwargs, obj.state, obj.items, obj.entries = args, kwargs, None, [], {}
        return obj

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        self.state = state

    def append(self, item: Any) -> None:
        self.items.append(item)

    def extend(self, items: Any) -> None:
        self.items.extend(items)

    def __setitem__(self, key: Any, value: Any) -> None:
        self.entries[key] = value

    def __repr__(self) -> str:
        return f"<inert {self.global_name}>"


def _inert_class(name: str) -> type[InertObject]:
    return type("Inert", (InertObject,), {"global_name": name, "__module__": __name__})


def _latin1_encode(text: str, encoding: str = "utf-8") -> bytes:
    """``_codecs.encode`` as pickles of protocols 0-2 use it for bytes (latin-1 only)."""
    if encoding not in ("latin1", "latin-1"):
        raise UnsafePickleError(f"a pickle asks _codecs.encode for encoding {encoding!r}; only latin-1 is used")
    return text.encode("latin1")


#: Real objects any restricted pickle may use: builtin types and containers, and the constructors pickle
#: itself emits (protocols 0-2 name the builtins module ``__builtin__``; find_class maps it).
PLAIN_GLOBALS: dict[str, Any] = {
    **{
        f"builtins.{name}": getattr(builtins, name)
        for name in (
            "list",
            "dict",
            "tuple",
            "set",
            "frozenset",
            "bytes",
            "bytearray",
            "str",
            "int",
            "float",
            "complex",
            "bool",
            "slice",
            "object",
        )
    },
    "collections.OrderedDict": OrderedDict,
    "_codecs.encode": _latin1_encode,
}


def _numpy_globals() -> dict[str, Any]:
    import numpy as np

    core = getattr(np, "_core", None) or np.core
    table: dict[str, Any] = {"numpy.ndarray": np.ndarray, "numpy.dtype": np.dtype}
    for package in ("numpy.core", "numpy._core"):  # NumPy 1 and 2 names of the same functions
        table[f"{package}.multiarray._reconstruct"] = core.multiarray._reconstruct
        table[f"{package}.multiarray.scalar"] = core.multiarray.scalar
        table[f"{package}.numeric._frombuffer"] = core.numeric._frombuffer
    return table


#: Real numpy constructors of arrays, dtypes and scalars from their bytes (no other code).
NUMPY_GLOBALS: dict[str, Any] = _numpy_globals()

#: Namespaces of data-only classes found in PyTorch Lightning checkpoints (hyper-parameters, loop state).
LIGHTNING_DATA_NAMESPACES = (
    "omegaconf.",
    "pytorch_lightning.",
    "lightning.",
    "lightning_fabric.",
    "typing.",
    "argparse.Namespace",
    "pathlib.",
    "collections.defaultdict",
    "numpy.",
    "torch.torch_version.",
    "copyreg._reconstructor",
)


class RestrictedUnpickler(pickle.Unpickler):
    """A pickle reader that resolves globals only from ``allowed``, makes names under ``inert_namespaces``
    :class:`InertObject` placeholders and refuses every other name (naming ``source`` and the global)."""

    def __init__(
        self,
        file: io.BufferedIOBase,
        source: str,
        allowed: Mapping[str, Any] | None = None,
        inert_namespaces: tuple[str, ...] = (),
        persistent_load: Callable[[Any], Any] | None = None,
    ) -> None:
        super().__init__(file)
        self.source = source
        self.allowed = {**PLAIN_GLOBALS, **(allowed or {})}
        self.inert_namespaces = inert_namespaces
        self._persistent_load = persistent_load

    def find_class(self, module: str, name: str) -> Any:
        # Protocol 2 writes Python 2's names (__builtin__.set, ...); map them as pickle itself does.
        if (module, name) in _compat_pickle.NAME_MAPPING:
            module, name = _compat_pickle.NAME_MAPPING[(module, name)]
        elif module in _compat_pickle.IMPORT_MAPPING:
            module = _compat_pickle.IMPORT_MAPPING[module]
        full = f"{module}.{name}"
        if full in self.allowed:
            return self.allowed[full]
        if self.inert_namespaces and full.startswith(self.inert_namespaces):
            return _inert_class(full)
        raise UnsafePickleError(
            f"{self.source} names {full}, which is not data (it could run code when loaded): refused, "
            "nothing from the file was run",
            full,
        )

    def persistent_load(self, pid: Any) -> Any:
        if self._persistent_load is None:
            raise UnreadablePickleError(f"{self.source}: unexpected persistent reference in the pickle")
        return self._persistent_load(pid)


_STORAGE_DTYPES = {
    "FloatStorage": torch.float32,
    "DoubleStorage": torch.float64,
    "HalfStorage": torch.float16,
    "BFloat16Storage": torch.bfloat16,
    "LongStorage": torch.int64,
    "IntStorage": torch.int32,
    "ShortStorage": torch.int16,
    "CharStorage": torch.int8,
    "ByteStorage": torch.uint8,
    "BoolStorage": torch.bool,
}


class _StorageType:
    """Stands for ``torch.<X>Storage`` in a checkpoint's persistent ids: just its dtype."""

    def __init__(self, dtype: torch.dtype) -> None:
        self.dtype = dtype


def _rebuild_tensor(
    storage: torch.Tensor, offset: int, size: tuple[int, ...], stride: tuple[int, ...], *_: Any
) -> torch.Tensor:
    return storage.as_strided(size, stride, offset)


def _rebuild_parameter(data: torch.Tensor, *_: Any) -> torch.Tensor:
    return data


_TORCH_GLOBALS: dict[str, Any] = {
    "torch._utils._rebuild_tensor_v2": _rebuild_tensor,
    "torch._utils._rebuild_tensor": _rebuild_tensor,
    "torch._utils._rebuild_parameter": _rebuild_parameter,
    "torch._utils._rebuild_parameter_with_state": _rebuild_parameter,
    **{f"torch.{name}": _StorageType(dtype) for name, dtype in _STORAGE_DTYPES.items()},
    **{f"torch.{name}": getattr(torch, name) for name in ("device", "Size")},
    **{str(dtype): dtype for dtype in (*_STORAGE_DTYPES.values(), torch.complex64, torch.complex128)},
}


def load_torch_checkpoint(path: str, inert_namespaces: tuple[str, ...] = LIGHTNING_DATA_NAMESPACES) -> Any:
    """The object a ``torch.save`` zip archive holds, with tensors on the CPU, read without running any of
    its code (see the module docstring). :class:`UnsafePickleError` when it names a global that is not
    data; :class:`UnreadablePickleError` when it is not a complete zip-format torch archive."""
    try:
        archive = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise UnreadablePickleError(f"{path} does not exist") from None
    except (zipfile.BadZipFile, OSError) as err:
        raise UnreadablePickleError(
            f"{path} is not a zip-format PyTorch checkpoint (truncated, corrupt, or saved by PyTorch < 1.6): {err}"
        ) from None
    with archive:
        names = archive.namelist()
        pickles = [n for n in names if n.endswith("/data.pkl") or n == "data.pkl"]
        if len(pickles) != 1:
            raise UnreadablePickleError(f"{path} is a zip archive but not a PyTorch checkpoint (no data.pkl)")
        prefix = pickles[0][: -len("data.pkl")]
        byteorder = archive.read(prefix + "byteorder").decode().strip() if prefix + "byteorder" in names else "little"
        if byteorder != "little":
            raise UnreadablePickleError(f"{path} was saved on a {byteorder}-endian machine, which is not supported")
        storages: dict[str, torch.Tensor] = {}

        def storage(pid: Any) -> torch.Tensor:
            if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
                raise UnreadablePickleError(f"{path}: unexpected persistent reference {pid!r:.80}")
            kind, key, numel = pid[1], str(pid[2]), int(pid[4])
            if not isinstance(kind, _StorageType):
                raise UnreadablePickleError(f"{path}: unknown storage type {kind!r:.80}")
            if key not in storages:
                try:
                    raw = archive.read(f"{prefix}data/{key}")
                except KeyError:
                    raise UnreadablePickleError(f"{path} is truncated: storage {key} is missing") from None
                flat = torch.frombuffer(bytearray(raw), dtype=kind.dtype) if raw else torch.empty(0, dtype=kind.dtype)
                if flat.numel() < numel:
                    raise UnreadablePickleError(f"{path} is truncated: storage {key} holds {flat.numel()} of {numel}")
                storages[key] = flat
            return storages[key]

        try:
            data = archive.read(pickles[0])
        except (zipfile.BadZipFile, OSError, EOFError) as err:
            raise UnreadablePickleError(f"{path} is truncated or corrupt: {err}") from None
        unpickler = RestrictedUnpickler(
            io.BytesIO(data), path, allowed=_TORCH_GLOBALS, inert_namespaces=inert_namespaces, persistent_load=storage
        )
        try:
            return unpickler.load()
        except (UnsafePickleError, UnreadablePickleError):
            raise
        except (pickle.UnpicklingError, EOFError, zipfile.BadZipFile, ValueError, TypeError, RuntimeError) as err:
            raise UnreadablePickleError(f"{path} is truncated or corrupt: {err}") from None
