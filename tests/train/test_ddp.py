"""DDP on CPU: two processes under torchrun with the gloo backend train and save one run."""

import os
import subprocess
import sys

from cliport.utils.files import load_torch
from cliport.utils.run_dir import RunDir


def test_torchrun_two_processes_gloo(tmp_path, make_synthetic_dataset):
    make_synthetic_dataset(str(tmp_path), n_episodes=2)
    run_dir = str(tmp_path / "run")
    cmd = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
        "-m", "cliport.cli.train", "--agent", "transporter_only", "--task", "place-red-in-green",
        "--n-demos", "2", "--n-steps", "3", "--batch-size", "1", "--data-dir", str(tmp_path), "--run-dir", run_dir,
        "--num-workers", "0", "--val-episodes", "0", "--checkpoint-steps", "3", "--log-every", "1", "--no-progress",
        "--device", "cpu", "--width", "0.125", "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32",
    ]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    assert RunDir(run_dir).checkpoint_steps() == [3]
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        rows = f.read().split()
    assert rows[0].startswith("step,") and len(rows) == 4
    assert rows[1].split(",")[-2] != ""  # samples/s counts both processes
    payload = load_torch(RunDir(run_dir).checkpoint("last"))
    assert payload["trainer"]["step"] == 3 and payload["agent"] == "transporter_only"
    assert run.stdout.count('"run_dir"') == 1  # one summary, from rank 0 only
