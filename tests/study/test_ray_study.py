"""A tiny study (2 tasks x 2 demo counts, tiny nets) on a 2-CPU Ray cluster started by the module's fixture:
the same rows and weights as the serial study, and every cell done exactly once when a worker running a cell,
and then the driver, are killed mid-training."""

import os
import signal
import subprocess
import sys
import time

import pytest

from cliport.cli import reproduce
from cliport.cli.common import run_cli
from cliport.data.generate import DemoConfig, generate
from cliport.study.cells import CellFiles, resume_step
from cliport.study.config import saved_config
from cliport.study.lock import lock_holder
from cliport.study.status import status_report
from cliport.utils.files import read_json
from cliport.utils.run_dir import RunDir

pytestmark = [pytest.mark.e2e, pytest.mark.whole_machine]
ray = pytest.importorskip("ray")

TASKS = ["block-insertion", "align-box-corner"]  # 3-action episodes: the cheapest evaluations
TINY = [
    "--tasks", *TASKS, "--agents", "transporter_only", "--recipes", "ravens", "--n-demos", "1", "2",
    "--batch-size", "1", "--camera-scale", "0.5", "--test-episodes", "1", "--width", "0.125",
    "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32", "--train-option", "num_workers=0",
    "--threads", "1", "--cell-cpus", "1", "--no-progress",
]  # fmt: skip


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("demos"))
    for task in TASKS:
        generate(task, "train", 2, DemoConfig.defaults(data_dir=root, workers=1, camera_scale=0.5), progress=False)
    return root


@pytest.fixture(scope="module")
def cluster():
    """A 2-CPU Ray started in this process (the study joins it: `--cluster local` uses a Ray already started
    here, a driver in another process joins it by address); shut down at the end, workers and all."""
    before = os.environ.get("RAY_AUTH_MODE")  # Ray 2.59+ turns token authentication on in this process's environ
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False,
             object_store_memory=100 * 1024**2)  # fmt: skip
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()
        if before is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = before


def _study(argv):
    run_cli(lambda: reproduce.main(argv))


def _done_events(config):
    """cell label -> its attempts' events."""
    return {cell.label(): CellFiles(config, cell).attempt_log() for cell in config.cells()}


def test_ray_gives_the_serial_rows(demos, cluster, tmp_path, capsys):
    common = [*TINY, "--data-dir", demos, "--n-steps", "4", "--checkpoint-steps", "4", "--val-episodes", "1"]
    serial, on_ray = str(tmp_path / "serial"), str(tmp_path / "ray")
    _study([*common, "--out", serial, "--cluster", "none"])
    _study([*common, "--out", on_ray, "--cluster", "local"])
    err = capsys.readouterr().err
    finished = [line for line in err.splitlines() if line.startswith("[")]
    assert len(finished) == 8 and "block-insertion transporter_only ravens 2 demos seed 0: test " in err
    for task in TASKS:
        rows = read_json(os.path.join(serial, task, "results.json"))
        assert rows == read_json(os.path.join(on_ray, task, "results.json"))
        assert [(r["n_demos"], r["val_selected_step"]) for r in rows["runs"]] == [(1, 4), (2, 4)]
        assert all(r["checkpoints"][0]["val"] is not None for r in rows["runs"])
    assert read_json(os.path.join(serial, "combined.json")) == read_json(os.path.join(on_ray, "combined.json"))
    # The weights too, bit for bit: each cell's torch threads are its own, not its worker's.
    import torch

    config = saved_config(serial)
    for cell in config.cells():
        run = CellFiles(config, cell).run_dir
        a = torch.load(RunDir(run).checkpoint(4), weights_only=True)["state_dict"]
        b = torch.load(RunDir(run.replace(serial, on_ray)).checkpoint(4), weights_only=True)["state_dict"]
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a), cell
    for events in _done_events(saved_config(on_ray)).values():
        assert [e["event"] for e in events] == ["start", "done"] and events[0]["pid"] != os.getpid()
    assert "4 cells, 4 done, 0 running, 0 waiting" in status_report(on_ray)


def _mid_training(config, skip=()):
    """A cell (not in ``skip``) whose attempt runs and has saved a resume point: (cell, its pid, saved step)."""
    for cell in config.cells():
        files = CellFiles(config, cell)
        holder = lock_holder(files.lock)
        if cell in skip or holder is None or files.record() is not None:
            continue
        step = resume_step(RunDir(files.run_dir))
        if 0 < step < config.n_steps:
            return cell, holder["pid"], step
    return None


def _wait_for(what, driver, timeout=300.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = what()
        if found:
            return found
        assert driver.poll() is None, "the driver ended before it was killed"
        time.sleep(0.1)
    raise AssertionError("timed out")


def test_killed_worker_and_driver_lose_nothing_and_repeat_nothing(demos, cluster, tmp_path):
    out = str(tmp_path / "s")
    # Two cells (one per task), trained at once on the 2 CPUs: one loses its worker, then the other its driver.
    argv = [*TINY, "--n-demos", "2", "--data-dir", demos, "--out", out, "--n-steps", "20", "--checkpoint-steps", "20",
            "--val-episodes", "0", "--train-option", "save_last_every=2", "--train-option", "log_every=2"]  # fmt: skip
    log = open(tmp_path / "driver.log", "w")
    driver = subprocess.Popen(
        [sys.executable, "-m", "cliport.cli.reproduce", *argv, "--cluster", cluster], stdout=log, stderr=log
    )
    try:
        config = _wait_for(lambda: os.path.exists(os.path.join(out, "study_config.json")) and saved_config(out), driver)
        # A Ray worker dies mid-training: Ray runs its cell again, from the step it had saved.
        worker_cell, pid, worker_step = _wait_for(lambda: _mid_training(config), driver)
        os.kill(pid, signal.SIGKILL)
        # Then the driver dies while another cell trains: Ray ends its tasks, and the rerun resumes them.
        driver_cell, _, driver_step = _wait_for(lambda: _mid_training(config, skip={worker_cell}), driver)
        driver.kill()
        driver.wait(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
        log.close()
    assert CellFiles(config, driver_cell).record() is None  # it was still training
    _study([*argv, "--cluster", cluster])
    events = _done_events(config)
    for label, cell_events in events.items():
        assert [e["event"] for e in cell_events].count("done") == 1, (label, cell_events)
    worker_starts = [e for e in events[worker_cell.label()] if e["event"] == "start"]
    assert len(worker_starts) >= 2 and worker_starts[1]["resume_step"] >= worker_step > 0
    driver_starts = [e for e in events[driver_cell.label()] if e["event"] == "start"]
    assert len(driver_starts) >= 2 and driver_starts[-1]["resume_step"] >= driver_step > 0
    for task in TASKS:
        rows = read_json(os.path.join(out, task, "results.json"))["runs"]
        assert [(r["n_demos"], r["checkpoints"][-1]["step"]) for r in rows] == [(2, 20)]
    records = [CellFiles(config, cell).record() for cell in config.cells()]
    assert max(r["attempt"] for r in records) >= 2 and all(r["summary"]["test_at_last"] is not None for r in records)
    report = status_report(out)
    assert "2 cells, 2 done" in report and "attempts, the last resumed from step" in report
