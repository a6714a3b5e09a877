"""The workcell's settings and the renderer they choose, apart from the simulator: a training run reads them
without importing PyBullet."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from cliport.env.egl import egl_works
from cliport.errors import ConfigError
from cliport.utils.config import defaults as config_defaults


@dataclass
class EnvConfig:
    """Workcell settings; defaults in ``configs/env.toml``.

    Args:
        camera_scale: camera resolution factor (1.0 renders 640 x 480; 0.5 renders 320 x 240, faster; the
            fused map is always 320 x 160); demos and validation of one run must use the same value.
        renderer: "auto" (EGL on an NVIDIA GPU, else TinyRenderer), "egl" or "cpu".
        sim_hz: physics steps per simulated second.
        settle_max_steps: steps allowed for the scene to come to rest after an action.
        settle_speed: objects slower than this (m/s) count as at rest.
        raw_images: include the three cameras' colour and depth images in every observation.
    """

    camera_scale: float
    renderer: str
    sim_hz: int
    settle_max_steps: int
    settle_speed: float
    raw_images: bool

    @classmethod
    def defaults(cls, **overrides: Any) -> EnvConfig:
        """The TOML defaults with the keyword overrides that are not None."""
        return config_defaults(cls, "env", **overrides)


def gpu_present() -> bool:
    """Whether an NVIDIA GPU is present (its device node), the condition for trying EGL."""
    return os.path.exists("/dev/nvidia0")


#: What demos, evaluations and runs record as the renderer: PyBullet's EGL plugin or TinyRenderer.
RENDERER_KINDS = ("egl", "tiny")
#: The renderer every command can be asked for: auto (EGL where a GPU is, else TinyRenderer), egl or cpu.
RENDERERS = ("auto", "egl", "cpu")


def check_renderer(choice: str, flag: str = "renderer") -> None:
    """ConfigError naming ``flag`` unless ``choice`` is one of :data:`RENDERERS`."""
    if choice not in RENDERERS:
        raise ConfigError(f"{flag} must be auto, egl or cpu, got {choice!r}")


def renderer_choice(choice: str) -> tuple[str, str]:
    """The renderer kind ("egl" or "tiny") the ``renderer`` setting ``choice`` gives on this machine, and why where
    it is TinyRenderer (else ""): the one place auto, egl and cpu are resolved, for every command (an
    :class:`~cliport.env.environment.Environment` renders with it; :func:`expected_renderer` answers without
    starting one). ConfigError unless ``choice`` is one of :data:`RENDERERS`.

    - cpu: tiny.
    - auto: tiny without an NVIDIA GPU (``/dev/nvidia0``): there EGL would render through Mesa's llvmpipe, which
      loads its own LLVM into the process, and triton (torch imports it when building an optimiser) segfaults next
      to it; TinyRenderer is as fast at the reduced resolution and safe. With a GPU, egl where PyBullet's
      eglRenderer plugin works (:func:`cliport.env.egl.egl_works`, probed once in a child process), else tiny.
    - egl: egl (an Environment raises where it fails).
    """
    check_renderer(choice)
    if choice == "cpu":
        return "tiny", ""
    if choice == "auto" and not gpu_present():
        return "tiny", "no GPU"
    if choice == "egl":
        return "egl", ""
    works, why = egl_works()
    return ("egl", "") if works else ("tiny", f"EGL fails here: {why}")


def expected_renderer(choice: str) -> str:
    """The renderer kind ("egl" or "tiny") an Environment with the ``renderer`` setting ``choice`` uses on
    this machine, found without starting one (:func:`renderer_choice`). (An Environment falls back to tiny if
    the plugin still fails to load; its :attr:`Environment.renderer_kind` is what it really uses.)"""
    return renderer_choice(choice)[0]
