"""Run a script of scripts/ in this process, as its command line would: one interpreter start instead of one per
call (torch, PyBullet and open_clip take seconds to import). Each script keeps at least one test that starts it
as a process."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


@pytest.fixture
def run_script(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> Callable:
    """``run_script(name, *args)`` -> a CompletedProcess of ``python scripts/NAME ARGS``: its ``main()`` called
    with that argv, its exit status (``sys.exit("error: ...")`` writes the message to stderr, status 1, as the
    interpreter does) and what it printed."""

    def run(name: str, *args: str) -> subprocess.CompletedProcess:
        path = SCRIPTS / name
        monkeypatch.syspath_prepend(str(SCRIPTS))  # as for a script: its folder first (scripts import each other)
        spec = importlib.util.spec_from_file_location(f"script_{path.stem}", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        monkeypatch.setattr(sys, "argv", [str(path), *args])
        capsys.readouterr()
        code = 0
        try:
            module.main()
        except SystemExit as stop:
            if isinstance(stop.code, str):
                print(stop.code, file=sys.stderr)
                code = 1
            else:
                code = stop.code or 0
        out = capsys.readouterr()
        return subprocess.CompletedProcess([str(path), *args], code, out.out, out.err)

    return run
