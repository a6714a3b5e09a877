"""The EGL probe: a plugin that ends its process is found in a child process, once, and "auto" falls back."""

from __future__ import annotations

import subprocess

import pytest

from cliport.env import config as env_config
from cliport.env import egl, environment
from cliport.env.environment import EnvConfig, Environment, expected_renderer

#: What PyBullet's eglRenderer plugin does without a usable EGL display: a message on stdout, then exit(1).
EXITS_LIKE_THE_PLUGIN = "import os, sys; print('failed to EGL with glad.'); sys.stdout.flush(); os._exit(1)"


@pytest.fixture
def no_answer_yet(monkeypatch):
    monkeypatch.setenv(egl.PROBE_ENV, "")  # so that the answer the test leaves is undone after it
    monkeypatch.delenv(egl.PROBE_ENV)


def test_a_plugin_that_ends_its_process_is_found_in_a_child(no_answer_yet, monkeypatch) -> None:
    monkeypatch.setattr(egl, "_PROBE", EXITS_LIKE_THE_PLUGIN)
    works, why = egl.egl_works()
    assert not works
    assert "code 1" in why and "failed to EGL with glad." in why
    assert egl.os.environ[egl.PROBE_ENV] == f"failed: {why}"  # inherited by workers started later


def test_a_working_probe_is_asked_once(no_answer_yet, monkeypatch) -> None:
    monkeypatch.setattr(egl, "_PROBE", "print('egl ok')")
    assert egl.egl_works() == (True, "")

    def refuse(*args, **kwargs):
        raise AssertionError("probed twice")

    monkeypatch.setattr(subprocess, "run", refuse)
    assert egl.egl_works() == (True, "")


def test_auto_falls_back_to_tinyrenderer_where_egl_fails_on_a_gpu(monkeypatch, caplog) -> None:
    monkeypatch.setattr(env_config, "gpu_present", lambda: True)
    monkeypatch.setenv(egl.PROBE_ENV, "failed: no EGL display")
    assert expected_renderer("auto") == "tiny"
    with Environment(EnvConfig.defaults(camera_scale=0.25, renderer="auto")) as env:
        assert env.renderer_kind == "tiny"
        assert "EGL fails here: no EGL display" in env.renderer_name
    assert "no EGL display" in caplog.text


def test_asking_for_egl_where_it_fails_names_why(monkeypatch) -> None:
    monkeypatch.setattr(env_config, "gpu_present", lambda: True)
    monkeypatch.setenv(egl.PROBE_ENV, "failed: no EGL display")
    with pytest.raises(RuntimeError, match="renderer='egl' was requested .* fails here: no EGL display"):
        Environment(EnvConfig.defaults(camera_scale=0.25, renderer="egl"))


def test_a_refused_renderer_leaves_no_simulator_connected(monkeypatch) -> None:
    monkeypatch.setattr(env_config, "gpu_present", lambda: True)
    monkeypatch.setenv(egl.PROBE_ENV, "failed: no EGL display")
    before = environment.p.connect(environment.p.DIRECT)
    environment.p.disconnect(physicsClientId=before)
    with pytest.raises(RuntimeError):
        Environment(EnvConfig.defaults(camera_scale=0.25, renderer="egl"))
    after = environment.p.connect(environment.p.DIRECT)
    environment.p.disconnect(physicsClientId=after)
    assert after == before  # the failed environment's client id was given back
