"""``cliport-reproduce --status OUT``: each cell of a study done, running or waiting, and the time left.

Read from the folder alone (no Ray needed): a cell is done when it has its completion record, running while
an attempt holds its lock, waiting otherwise (an interrupted one says where it stopped). The time left is the
finished cells' durations (those of the same task first) times the work left, spread over the cells running at
once.
"""

from __future__ import annotations

import csv
import os
import statistics
import time
from typing import Any

from cliport.study.cells import CellFiles
from cliport.study.config import StudyConfig, saved_config
from cliport.study.lock import driver_holding, lock_holder
from cliport.study.report import row_score
from cliport.utils.run_dir import RunDir


def _trained_steps(run_dir: str) -> int:
    """How far a run has trained, as far as its files say without loading one: the last step metrics.csv
    logged or the last scheduled checkpoint, whichever is later (0 before either)."""
    run = RunDir(run_dir)
    logged = 0
    if os.path.exists(run.metrics):
        with open(run.metrics, newline="") as f:
            rows = list(csv.DictReader(f))
        try:
            logged = int(rows[-1]["step"]) if rows else 0
        except (KeyError, ValueError):
            logged = 0
    return max([logged, *run.checkpoint_steps()])


def cell_states(config: StudyConfig) -> list[dict[str, Any]]:
    """One dict per cell: task, agent, recipe, n_demos, seed, state (done/running/waiting), test, minutes,
    step (trained steps), detail."""
    rows = []
    for cell in config.cells():
        files = CellFiles(config, cell)
        row: dict[str, Any] = {**vars(cell), "test": None, "minutes": None, "detail": ""}
        record = files.record()
        step = config.n_steps if record else _trained_steps(files.run_dir)
        row["step"] = step
        starts = [e for e in files.attempt_log() if e.get("event") == "start"]
        if record is not None:
            row["state"] = "done"
            row["test"] = row_score(record["summary"])[0]
            row["minutes"] = record["minutes"]
            if record.get("attempt", 1) > 1:
                row["detail"] = (
                    f"{record['attempt']} attempts, the last resumed from step {record['resumed_from_step']}"
                )
        elif lock_holder(files.lock) is not None:
            row["state"] = "running"
            training = f"step {step}/{config.n_steps}" if step < config.n_steps else "evaluating"
            elapsed = (time.time() - starts[-1]["time"]) / 60 if starts else 0.0
            row["detail"] = f"{training}, attempt {len(starts)}, {elapsed:.1f} min"
        else:
            row["state"] = "waiting"
            if starts:
                from cliport.study.cells import resume_step

                row["step"] = resume_step(RunDir(files.run_dir))
                row["detail"] = f"interrupted: resumes from step {row['step']}/{config.n_steps} (checkpoints/last.pt)"
        rows.append(row)
    return rows


def _duration(minutes: float) -> str:
    hours, rest = divmod(max(1, round(minutes)), 60)
    return f"{hours} h {rest} min" if hours else f"{rest} min"


def time_left(rows: list[dict[str, Any]], n_steps: int) -> str:
    """The estimate's line: each cell left takes the mean minutes of the finished cells most like it (same task,
    agent and recipe; else same task; else all) times its untrained fraction, over the cells running at once."""
    done = [r for r in rows if r["state"] == "done" and r["minutes"] is not None]
    left = [r for r in rows if r["state"] != "done"]
    if not left:
        return "time left: none, every cell is done"
    if not done:
        return f"time left: unknown until a cell finishes ({len(left)} cells to go)"

    def minutes(row: dict[str, Any]) -> float:
        for same in (("task", "agent", "recipe"), ("task",), ()):
            like = [d["minutes"] for d in done if all(d[k] == row[k] for k in same)]
            if like:
                return statistics.mean(like)
        raise AssertionError("unreachable: done is not empty")

    work = sum(minutes(r) * (1 - min(r["step"], n_steps) / n_steps) for r in left)
    at_once = max(1, sum(r["state"] == "running" for r in rows))
    mean = statistics.mean(d["minutes"] for d in done)
    return (
        f"time left: about {_duration(work / at_once)} ({len(left)} cells to go; the {len(done)} finished took "
        f"{mean:.1f} min each on average; {at_once} at a time)"
    )


def status_report(out: str) -> str:
    """The status table of the study in ``out`` and its time left, as text."""
    config = saved_config(out)
    rows = cell_states(config)
    driver = driver_holding(out)
    counts = {state: sum(r["state"] == state for r in rows) for state in ("done", "running", "waiting")}
    who = f"a driver runs it (pid {driver['pid']} on {driver['host']})" if driver else "no driver runs it"
    lines = [
        f"study {out}: {len(rows)} cells, {counts['done']} done, {counts['running']} running, "
        f"{counts['waiting']} waiting; {who}",
        "",
    ]
    header = ["task", "agent", "recipe", "demos", "seed", "state", "test", "minutes", "detail"]
    table = [header] + [
        [
            r["task"],
            r["agent"],
            r["recipe"],
            str(r["n_demos"]),
            str(r["seed"]),
            r["state"],
            "-" if r["test"] is None else f"{r['test']:.1f}",
            "-" if r["minutes"] is None else f"{r['minutes']:.1f}",
            r["detail"],
        ]
        for r in rows
    ]
    widths = [max(len(line[i]) for line in table) for i in range(len(header))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(line, widths, strict=True)).rstrip() for line in table]
    lines += ["", time_left(rows, config.n_steps)]
    return "\n".join(lines)
