"""scripts/bench_train.py: cliport-train's loop timed at a tiny width on the CPU, with the reference's benchmark
run beside it (a stand-in ref_bench.py here: the real one at the published size takes minutes per step on a CPU)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "bench_train.py"
TINY = ["--agents", "transporter_only", "--steps", "2", "--log-every", "1", "--n-rotations", "4", "--act-repeats", "1"]

#: A stand-in for the reference folder's ref_bench.py: it records how it was called and reports fixed timings.
FAKE_REF_BENCH = textwrap.dedent(
    """
    import json, os, sys
    args = dict(zip(sys.argv[1::2], sys.argv[2::2]))
    env = {"argv": sys.argv[1:], "cwd": os.getcwd(), "pythonpath": os.environ.get("PYTHONPATH", "")}
    out = {"transporter": {"train_step_s": 4.0, "train_samples_per_s": 0.25, "act_s": 3.0, "env": env}}
    with open(args["--out"], "w") as f:
        json.dump(out, f)
    print(json.dumps(out))
    """
)


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=1200)


@pytest.mark.e2e
def test_times_the_training_loop_act_loader_and_the_reference(tmp_path):
    reference = tmp_path / "reference"
    reference.mkdir()
    (reference / "ref_bench.py").write_text(FAKE_REF_BENCH)
    saved = tmp_path / "bench.json"
    out = _run(*TINY, "--profile", "--reference-dir", str(reference), "--reference-steps", "3", "--out", str(saved))
    assert out.returncode == 0, out.stderr[-3000:]
    report = json.loads(out.stdout)
    assert json.loads(saved.read_text()) == report and not os.path.exists(f"{saved}.partial")
    assert report["device"] == "cpu" and report["width"] == 0.125 and report["train_graphs"] is True
    ours = report["agents"]["transporter_only"]
    batch1 = ours["train"]["batch1"]
    assert batch1["timed_steps"] == 2 and batch1["samples_per_s"] == batch1["steps_per_s"] > 0
    assert batch1["step_kinds"] == {"graph_replays": 0, "eager": 3}  # a CPU trains eagerly
    assert ours["act"]["act_ms"] > 0 and report["loader"]["samples_per_s"] > 0
    rows = ours["profile"]["batch1"]["top_ops"]
    assert len(rows) == 15 and all(row["calls"] > 0 and 0 < row["share"] <= 1 for row in rows)
    assert any(row["op"] == "aten::convolution_backward" for row in rows)
    ref = report["reference"]
    env = ref["env"]
    assert env["argv"] == ["--device", "cpu", "--steps", "3", "--out", env["argv"][5], "--agent", "transporter"]
    assert env["cwd"] == str(reference) and env["pythonpath"].split(os.pathsep)[0] == str(reference)
    ratio = report["ratio_to_reference"]["transporter_only"]
    assert ratio["train_batch1"] == pytest.approx(batch1["samples_per_s"] / 0.25)
    assert ratio["act"] == pytest.approx(3000.0 / ours["act"]["act_ms"])
    assert "width 0.125" in report["ratio_note"]


def test_bad_input_is_an_argparse_error(run_script):
    for args, phrase in ((["--width", "0"], "--width"), (["--reference-dir", "/nonexistent"], "ref_bench.py")):
        out = run_script("bench_train.py", *args)
        assert out.returncode == 2 and phrase in out.stderr and "Traceback" not in out.stderr, out.stderr
