"""The environment of a measurement, as a results row records it: processor (model, family, the vector units that
decide CPU speed), cores, GPU, the versions of the libraries that set the numbers, the commit and the command."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from importlib import metadata
from typing import Any

import torch

#: Processor flags a CPU figure depends on (from /proc/cpuinfo): the vector units and native bfloat16 / AMX.
SPEED_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_bf16", "amx_tile")
#: Distributions whose versions a results row names.
PACKAGES = ("torch", "open_clip_torch", "pybullet", "numpy")


def _cpuinfo(path: str = "/proc/cpuinfo") -> dict[str, str]:
    """The first processor's fields of /proc/cpuinfo (empty where there is none, e.g. not Linux)."""
    fields: dict[str, str] = {}
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                if not line.strip():
                    break
                key, _, value = line.partition(":")
                fields[key.strip()] = value.strip()
    except OSError:
        pass
    return fields


def cpu_description(path: str = "/proc/cpuinfo") -> dict[str, Any]:
    """``{"model", "vendor", "family", "model_number", "flags", "cores", "kernels"}`` of this machine's processor:
    ``flags`` lists which of :data:`SPEED_FLAGS` it has, ``kernels`` the CPU capability torch runs with."""
    info = _cpuinfo(path)
    flags = set(info.get("flags", "").split())
    family = info.get("cpu family")
    model_number = info.get("model")
    return {
        "model": info.get("model name") or platform.processor() or platform.machine(),
        "vendor": info.get("vendor_id"),
        "family": int(family) if family and family.isdigit() else None,
        "model_number": int(model_number) if model_number and model_number.isdigit() else None,
        "flags": [flag for flag in SPEED_FLAGS if flag in flags],
        "cores": os.cpu_count(),
        "kernels": torch.backends.cpu.get_cpu_capability(),
    }


def cpu_line(cpu: dict[str, Any]) -> str:
    """One line for a results page: e.g. "2-core AMD EPYC (family 25, AVX2, no AVX-512)"."""
    vector = "AVX-512" if "avx512f" in cpu["flags"] else "AVX2, no AVX-512" if "avx2" in cpu["flags"] else "no AVX2"
    family = f"family {cpu['family']}, " if cpu.get("family") is not None else ""
    return f"{cpu['cores']}-core {cpu['model']} ({family}{vector})"


def _commit() -> str | None:
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        out = subprocess.run(
            ["git", "-C", here, "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def measurement_environment(command: list[str] | None = None) -> dict[str, Any]:
    """What a results row records of where and how it was measured: ``cpu`` (:func:`cpu_description`), ``cpu_line``,
    ``gpu`` (the CUDA device's name, or None), ``threads`` (torch's intra-op threads), ``versions`` (python and
    :data:`PACKAGES`), ``commit`` (the checkout's, None outside one) and ``command`` (default: this process's)."""
    cpu = cpu_description()
    return {
        "cpu": cpu,
        "cpu_line": cpu_line(cpu),
        "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
        "threads": torch.get_num_threads(),
        "versions": {"python": platform.python_version(), **{name: _version(name) for name in PACKAGES}},
        "commit": _commit(),
        "command": " ".join(command if command is not None else [os.path.basename(sys.argv[0]), *sys.argv[1:]]),
    }


if __name__ == "__main__":  # python -m cliport.utils.machine: this machine's record, as a results row quotes it
    import json

    print(json.dumps(measurement_environment(), indent=2))
