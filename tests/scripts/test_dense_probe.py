"""scripts/dense_probe.py: one error line for bad input; one scene probed end to end."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "dense_probe.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


def test_bad_input_is_one_line(one_error_line):
    done = _run("--clip-weights", "random", "--semantic-encoder", "cliport-RN-tiny", "--scenes", "0")
    one_error_line(done.returncode, done.stderr, "--scenes must be >= 1")
    done = _run("--clip-weights", "random")
    one_error_line(done.returncode, done.stderr, "--clip-weights random needs --semantic-encoder")


@pytest.mark.e2e  # the library's own test covers the same path in the default tier
def test_probes_a_scene_at_a_scale_and_writes_its_json(tmp_path):
    out = tmp_path / "dense.json"
    done = _run("--clip-weights", "random", "--semantic-encoder", "cliport-RN-tiny", "--scenes", "1",
                "--scales", "0.5", "--out", str(out))  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    part = report["scales"]["0.5"]
    assert part["scenes"] == 1 and part["seen"]["n"] + part["unseen"]["n"] == 3
    assert report["environment"]["cpu"]["cores"] >= 1 and report["semantic_encoder"] == "cliport-RN-tiny"
