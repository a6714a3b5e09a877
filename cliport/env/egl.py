"""Whether PyBullet's EGL renderer works on this machine, asked once in a child process.

The eglRenderer plugin ends the whole process (``exit(1)``, its message on the native stdout) when it finds
no usable EGL display, for example on a GPU machine whose container lacks NVIDIA's EGL library. Loaded in
a simulator or evaluation worker, that kills the worker without a Python error. So before a process loads
the plugin, a short child process loads it and renders one image; the answer is kept in the environment
variable :data:`PROBE_ENV`, which processes started later (workers) inherit, so a machine is probed once
per session of processes.
"""

from __future__ import annotations

import os
import subprocess
import sys

#: "ok", or "failed: <why>": set by :func:`egl_works` and inherited by child processes.
PROBE_ENV = "CLIPORT_EGL_PROBE"
#: Seconds the probe may take (a first EGL start can be slow on a busy machine).
PROBE_TIMEOUT = 60.0

_PROBE = """
import importlib.util
import pybullet as p
spec = importlib.util.find_spec("eglRenderer")
if spec is None or not spec.origin:
    raise SystemExit("PyBullet's eglRenderer plugin is not installed")
client = p.connect(p.DIRECT)
if p.loadPlugin(spec.origin, "_eglRendererPlugin", physicsClientId=client) < 0:
    raise SystemExit("PyBullet's eglRenderer plugin did not load")
p.getCameraImage(8, 8, renderer=p.ER_BULLET_HARDWARE_OPENGL, physicsClientId=client)
print("egl ok")
"""


def egl_works() -> tuple[bool, str]:
    """(works, why not): whether a child process could load the eglRenderer plugin and render with it.
    The first call on a machine runs the probe (about a second); later calls, in this process or in its
    child processes, read :data:`PROBE_ENV`."""
    answer = os.environ.get(PROBE_ENV)
    if answer is None:
        answer = _probe()
        os.environ[PROBE_ENV] = answer
    if answer == "ok":
        return True, ""
    return False, answer.removeprefix("failed: ")


def _probe() -> str:
    try:
        done = subprocess.run(
            [sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=PROBE_TIMEOUT, check=False
        )
    except subprocess.TimeoutExpired:
        return f"failed: the EGL probe took over {PROBE_TIMEOUT:.0f} s"
    if done.returncode == 0 and "egl ok" in done.stdout:
        return "ok"
    lines = [line.strip() for line in (done.stderr + done.stdout).splitlines() if line.strip()]
    lines = [line for line in lines if not line.startswith("pybullet build time")]
    detail = lines[-1] if lines else "no message"
    return f"failed: the EGL probe exited with code {done.returncode} ({detail})"


__all__ = ["PROBE_ENV", "PROBE_TIMEOUT", "egl_works"]
