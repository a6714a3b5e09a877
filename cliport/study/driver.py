"""The study's driver: runs (or resumes) every cell, one after another here or as Ray tasks, and gathers the
results: each task's ``results.json``, ``table.md`` and plot as soon as its cells are done, and the table over
tasks (``combined.md``) at the end.

One driver per study folder (:func:`~cliport.study.lock.study_lock`), and only with the settings the folder was
started with (:func:`~cliport.study.config.check_settings`). The cells themselves are idempotent
(:func:`~cliport.study.cells.run_cell`), so a driver that dies, or is killed, is simply run again.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
from typing import Any

from cliport.study.cells import CellError, CellFiles, generate_demos, run_cell
from cliport.study.config import SETTINGS_FILE, Cell, StudyConfig, check_settings
from cliport.study.lock import study_lock
from cliport.study.report import row_score, task_results, write_combined, write_task_results
from cliport.utils.files import write_json


class _Gather:
    """Hears of finished cells, prints a line for each, and writes a task's results once its cells are done."""

    def __init__(self, config: StudyConfig, cells: list[Cell]) -> None:
        self.config = config
        self.cells = cells
        self.left = {task: 0 for task in config.study_tasks()}
        for cell in cells:
            if CellFiles(config, cell).record() is None:
                self.left[cell.task] += 1
        self.n_done = len(cells) - sum(self.left.values())
        self.results: dict[str, dict[str, Any]] = {}

    def write_finished_tasks(self) -> None:
        for task, left in self.left.items():
            if left == 0 and task not in self.results:
                self._write_task(task)

    def finished(self, cell: Cell, record: dict[str, Any]) -> None:
        self.n_done += 1
        value, _, which = row_score(record["summary"])
        score = "-" if value is None else f"{value:.1f}"
        where = f"val-selected step {record['summary']['val_selected_step']}" if which == "val-selected" else which
        demos = f"{cell.n_demos} demo{'s' if cell.n_demos != 1 else ''}"
        line = f"{cell.task} {cell.agent} {cell.recipe} {demos} seed {cell.seed}"
        minutes = record["minutes"]
        print(
            f"[{self.n_done}/{len(self.cells)}] {line}: test {score} ({where} checkpoint), {minutes:.1f} min",
            file=sys.stderr,
            flush=True,
        )
        self.left[cell.task] -= 1
        if self.left[cell.task] == 0:
            self._write_task(cell.task)

    def _write_task(self, task: str) -> None:
        summaries = []
        for cell in self.cells:
            if cell.task == task:
                record = CellFiles(self.config, cell).record()
                assert record is not None, cell
                summaries.append(record["summary"])
        results = task_results(task, self.config.n_steps, self.config.training_seeds(), summaries)
        write_task_results(self.config.task_dir(task), results)
        self.results[task] = results


def run_study(config: StudyConfig, progress: bool = True, wait: bool = False) -> dict[str, Any]:
    """Run (or resume) every cell of the study and write each task's results and the table over tasks; returns
    ``{"tasks": [results of each task]}``. ``wait``: wait for another driver of the folder instead of refusing."""
    from cliport.study.cluster import check_cluster

    check_cluster(config.cluster)
    # The driver's machine decides the default, not each worker's.
    config = dataclasses.replace(config, cell_cpus=config.resolved_cell_cpus())
    cells = config.cells()
    for cell in cells:  # every run's train config: a bad setting fails before any work starts
        config.train_config(cell.agent, cell.n_demos, cell.seed, cell.recipe, cell.task)
    config.eval_worker_count(config.test_episodes)
    if config.val_episodes > 0:
        config.eval_worker_count(config.val_episodes)
    with study_lock(config.out, wait), contextlib.ExitStack() as stack:
        check_settings(config)
        ray = None
        if config.cluster != "none":  # joined before the folder records anything: a failed join leaves it as it was
            from cliport.evaluation.engine import usable_cores
            from cliport.study.cluster import connected, gpus_per_cell

            ray = stack.enter_context(connected(config.cluster, usable_cores()))
            gpus_per_cell(ray, config)
        write_json(os.path.join(config.out, SETTINGS_FILE), dataclasses.asdict(config))
        gather = _Gather(config, cells)
        gather.write_finished_tasks()
        todo = [cell for cell in cells if CellFiles(config, cell).record() is None]
        if gather.n_done:
            print(f"{gather.n_done} of {len(cells)} cells were already done in {config.out}", file=sys.stderr)
        failed: list[tuple[Cell, str]] = []
        if config.cluster == "none":
            for task in config.study_tasks():
                task_cells = [cell for cell in todo if cell.task == task]
                if task_cells:
                    for shard in range(config.demo_shards):
                        generate_demos(config, task, shard, progress)
                for cell in task_cells:
                    gather.finished(cell, run_cell(config, cell, progress))
        else:
            from cliport.study.cluster import run_cells

            # Ray's workers may start anywhere (another node, another working directory).
            anywhere = dataclasses.replace(
                config, out=os.path.abspath(config.out), data_dir=os.path.abspath(config.data_dir)
            )
            demo_tasks = list(dict.fromkeys(cell.task for cell in todo))
            failed = run_cells(ray, anywhere, todo, demo_tasks, gather.finished)
        finished = [gather.results[task] for task in config.study_tasks() if task in gather.results]
        write_combined(config.out, finished)
        if failed:
            cell, line = failed[0]
            raise CellError(
                f"{len(failed)} of {len(cells)} cells failed (the first, {cell.label()}: {line}); "
                "the others' results are kept, and running the command again retries the failed ones"
            )
    return {"tasks": finished}
