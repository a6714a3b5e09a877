"""cliport-reproduce's bad input: one ``error:`` line, exit status 2, before any work starts."""

import dataclasses
import os
import socket
import sys
import time

import pytest

from cliport.cli import reproduce
from cliport.cli.common import run_cli
from cliport.study import StudyConfig
from cliport.study.config import SETTINGS_FILE
from cliport.study.lock import study_lock
from cliport.utils.files import write_json

BASE = ["--agents", "transporter_only", "--recipes", "ravens", "--n-demos", "1", "--n-steps", "10", "--no-progress"]


def _fail(capsys, argv, tmp_path):
    """Run the command (its demos, were it to get that far, in tmp_path/d); (exit code, stderr)."""
    argv = [*argv, "--data-dir", str(tmp_path / "d")]
    with pytest.raises(SystemExit) as e:
        run_cli(lambda: reproduce.main(argv))
    return e.value.code, capsys.readouterr().err


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unknown_task_in_tasks(tmp_path, capsys, one_error_line):
    out = str(tmp_path / "s")
    code, err = _fail(capsys, [*BASE, "--tasks", "block-insertion", "block-insertoin", "--out", out], tmp_path)
    one_error_line(code, err, "block-insertoin", "did you mean block-insertion", status=2)
    assert not os.path.exists(out)


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["--task", "block-insertion", "--tasks", "align-box-corner"], "--task or --tasks, not both"),
        (["--tasks", "block-insertion", "align-box-corner"], "--out is required when several tasks are studied"),
        (["--task", "block-insertion", "--train-option", "seed=3"], "--train-option cannot set seed"),
        (["--task", "block-insertion", "--threads", "0"], "--threads must be >= 1"),
        (["--task", "block-insertion", "--cluster", "nowhere"], "--cluster must be none, local, auto or"),
    ],
)
def test_bad_flags(tmp_path, capsys, one_error_line, argv, phrase):
    pytest.importorskip("ray")  # --cluster nowhere is read once Ray imports
    out = [] if "several" in phrase else ["--out", str(tmp_path / "s")]
    code, err = _fail(capsys, [*BASE, *argv, *out], tmp_path)
    one_error_line(code, err, phrase, status=2)
    assert not os.path.exists(tmp_path / "d") and not os.path.exists(tmp_path / "s")


def test_an_unreachable_cluster_is_one_line_quickly(tmp_path, capsys, one_error_line):
    pytest.importorskip("ray")
    address = f"127.0.0.1:{_free_port()}"
    start = time.perf_counter()
    code, err = _fail(
        capsys, [*BASE, "--task", "block-insertion", "--cluster", address, "--out", str(tmp_path / "s")], tmp_path
    )
    one_error_line(code, err, f"no Ray cluster answers at {address}", "ray start --head", status=2)
    assert time.perf_counter() - start < 30  # a short connect timeout, not Ray's minute of retries
    assert not os.path.exists(tmp_path / "s")


def test_without_ray_the_cluster_asks_for_the_extra(tmp_path, capsys, one_error_line, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    code, err = _fail(
        capsys, [*BASE, "--task", "block-insertion", "--cluster", "local", "--out", str(tmp_path)], tmp_path
    )
    one_error_line(code, err, "--cluster local needs Ray", 'pip install -e ".[cluster]"', status=2)


def test_a_folder_with_other_settings(tmp_path, capsys, one_error_line):
    out = tmp_path / "s"
    saved = StudyConfig(task="block-insertion", agents=["transporter_only"], recipes=["ravens"], n_demos=[1],
                        n_steps=20, out=str(out), data_dir="data")  # fmt: skip
    write_json(out / SETTINGS_FILE, dataclasses.asdict(saved))
    code, err = _fail(capsys, [*BASE, "--task", "block-insertion", "--out", str(out)], tmp_path)
    one_error_line(code, err, f"{out} holds a study with other settings (n_steps 20 there, 10 here)", status=2)
    assert sorted(os.listdir(out)) == [".lock", SETTINGS_FILE]  # nothing else started


def test_a_second_driver_refuses(tmp_path, capsys, one_error_line):
    out = str(tmp_path / "s")
    with study_lock(out):
        code, err = _fail(capsys, [*BASE, "--task", "block-insertion", "--out", out], tmp_path)
    one_error_line(code, err, f"another cliport-reproduce (pid {os.getpid()} on", "--wait", status=2)


def test_status_of_a_folder_without_a_study(tmp_path, capsys, one_error_line):
    code, err = _fail(capsys, ["--status", str(tmp_path)], tmp_path)
    one_error_line(code, err, f"{tmp_path} holds no study (no {SETTINGS_FILE})", status=2)
