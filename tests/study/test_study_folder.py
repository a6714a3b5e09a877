"""The study's task groups, the settings a study folder keeps, its locks, its status and the table over tasks
(no training, no Ray)."""

import dataclasses
import json
import os

import pytest

from cliport import tasks
from cliport.errors import ConfigError, UnknownNameError
from cliport.evaluation.published import published_results
from cliport.study import StudyConfig, combined_table, expand_tasks, study_groups
from cliport.study.cells import CellFiles
from cliport.study.config import SETTINGS_FILE, check_settings
from cliport.study.lock import FileLock, StudyBusyError, driver_holding, lock_holder, study_lock
from cliport.study.report import summarise_run, task_results
from cliport.study.status import status_report
from cliport.utils.files import save_torch, write_json
from cliport.utils.run_dir import RunDir


def _config(out, **overrides) -> StudyConfig:
    base = dict(tasks=["block-insertion", "align-box-corner"], agents=["transporter_only"], recipes=["ravens"],
                n_demos=[1, 10], n_steps=40, out=str(out), data_dir="d")  # fmt: skip
    return StudyConfig(**{**base, **overrides})


def test_the_papers_tables_are_groups_of_registered_tasks():
    groups = study_groups()
    assert (
        set(groups["transporter-paper"]) == set(tasks.groups()["multi-ravens"])
        and len(groups["transporter-paper"]) == 10
    )
    # CLIPort's Table 1: our names for its 18 rows, e.g. its packing-box-pairs is our packing-boxes-pairs.
    assert set(groups["cliport-table1"]) == set(tasks.groups()["multi-language-conditioned"])
    assert len(groups["cliport-table1"]) == len(published_results()["cliport_table1_test"]) == 18
    assert "packing-boxes-pairs-seen-colors" in groups["cliport-table1"]
    assert expand_tasks(["block-insertion", "transporter-paper"]) == groups["transporter-paper"]  # each task once
    assert expand_tasks(["multi-ravens"]) == tasks.groups()["multi-ravens"]
    with pytest.raises(UnknownNameError, match="no-such-task"):
        expand_tasks(["block-insertion", "no-such-task"])


def test_cells_and_their_folders():
    config = _config("s", seeds=[0, 1])
    cells = config.cells()
    assert len(cells) == 2 * 2 * 2 and cells[0].label() == "block-insertion transporter_only ravens n1 s0"
    files = CellFiles(config, cells[-1])
    assert files.run_dir == "s/align-box-corner/runs/transporter_only-ravens-n10-s1"
    assert files.result == "s/align-box-corner/cells/transporter_only-ravens-n10-s1/result.json"
    # One task: its results stay in the study folder itself, as before several tasks could be studied.
    one = StudyConfig(
        task="block-insertion", agents=["transporter_only"], n_demos=[1], n_steps=1, out="s", data_dir="d"
    )
    assert CellFiles(one, one.cells()[0]).run_dir == "s/runs/transporter_only-ravens-n1"
    with pytest.raises(ConfigError, match="--train-option cannot set n_steps"):
        _config("s", train_options={"n_steps": 3}).train_config("transporter_only", 1)


def test_a_folder_is_continued_only_with_its_settings(tmp_path):
    config = _config(tmp_path)
    check_settings(config)  # a new folder
    write_json(tmp_path / SETTINGS_FILE, dataclasses.asdict(config))
    check_settings(dataclasses.replace(config, cluster="local", eval_workers=2, data_dir="elsewhere"))  # not settings
    with pytest.raises(ConfigError) as e:
        check_settings(dataclasses.replace(config, n_steps=20, tasks=["block-insertion"]))
    assert "tasks ['block-insertion', 'align-box-corner'] there, ['block-insertion'] here" in str(e.value)
    assert "n_steps 40 there, 20 here" in str(e.value) and "another --out" in str(e.value)
    # A folder written before a setting existed is compared on the settings it records (a --task study too).
    old = {k: v for k, v in dataclasses.asdict(config).items() if k not in ("threads", "tasks", "train_options")}
    write_json(tmp_path / SETTINGS_FILE, {**old, "task": "block-insertion"})
    check_settings(dataclasses.replace(config, tasks=["block-insertion"], threads=3))
    with pytest.raises(ConfigError, match="recipes"):
        check_settings(dataclasses.replace(config, tasks=["block-insertion"], recipes=["cliport"]))


def test_one_driver_per_folder_and_one_attempt_per_cell(tmp_path):
    assert driver_holding(str(tmp_path)) is None
    with study_lock(str(tmp_path)):
        holder = driver_holding(str(tmp_path))
        assert holder["pid"] == os.getpid()
        with pytest.raises(StudyBusyError, match=f"pid {os.getpid()} on .* is running the study in .*--wait"):
            with study_lock(str(tmp_path)):
                pass
    assert driver_holding(str(tmp_path)) is None
    with study_lock(str(tmp_path)):  # free again
        pass
    path = str(tmp_path / "cells" / "x" / ".lock")
    with FileLock(path, wait=True):
        assert lock_holder(path)["pid"] == os.getpid()
    assert lock_holder(path) is None


def _summary(task, n, test):
    val = {"checkpoints": {"40": {"mean_score": test}}, "best_step": 40}
    return {**summarise_run(task, "transporter_only", n, {"40": test}, val, "ravens"), "seed": 0}


def test_status_says_done_running_and_waiting_with_the_time_left(tmp_path):
    config = _config(tmp_path)
    write_json(tmp_path / SETTINGS_FILE, dataclasses.asdict(config))
    done, running, interrupted, untouched = config.cells()
    files = CellFiles(config, done)
    write_json(files.result, {"summary": _summary(done.task, 1, 60.0), "minutes": 10.0, "attempt": 2,
                              "resumed_from_step": 20})  # fmt: skip
    for cell, step in ((running, 10), (interrupted, 30)):
        files = CellFiles(config, cell)
        files.log_event({"event": "start", "attempt": 1, "pid": 1, "host": "h", "time": 0.0, "resume_step": 0})
        os.makedirs(files.run_dir)
        with open(os.path.join(files.run_dir, "metrics.csv"), "w") as f:
            f.write(f"step,loss\n{step},1.0\n")
        save_torch({"trainer": {"step": step - 4}}, RunDir(files.run_dir).checkpoint("last"))
    with FileLock(CellFiles(config, running).lock):
        report = status_report(str(tmp_path))
    lines = report.splitlines()
    assert lines[0].startswith(f"study {tmp_path}: 4 cells, 1 done, 1 running, 2 waiting; no driver runs it")
    rows = {tuple(line.split()[:6]) for line in lines[3:7]}
    assert ("block-insertion", "transporter_only", "ravens", "1", "0", "done") in rows
    assert "60.0  10.0     2 attempts, the last resumed from step 20" in report
    assert "running  -     -        step 10/40, attempt 1" in report
    assert "waiting  -     -        interrupted: resumes from step 26/40 (checkpoints/last.pt)" in report
    # Left: the running cell 30/40 of its task's 10 minutes, the interrupted one 14/40 and the last one all of
    # the overall mean's (no cell of their task is done), one running at a time.
    assert lines[-1] == (
        "time left: about 21 min (3 cells to go; the 1 finished took 10.0 min each on average; 1 at a time)"
    )


def test_the_table_over_tasks_stands_beside_the_published_numbers():
    insertion = [_summary("block-insertion", 1, 60.0), _summary("block-insertion", 10, 80.0)]
    results = [
        task_results("block-insertion", 40, [0], insertion),
        task_results("align-box-corner", 40, [0], [_summary("align-box-corner", 1, 20.0)]),
    ]
    table = combined_table(results)
    assert "## transporter_only, ravens recipe" in table and "| task | 1 demo | 10 demos |" in table
    assert "| block-insertion | 60.0 / 100.0 | 80.0 / 100.0 |" in table
    assert "| align-box-corner | 20.0 / 35.0 | not run |" in table
    json.dumps(results)  # combined.json holds them as they are
