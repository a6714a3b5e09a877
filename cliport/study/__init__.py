"""The reproduction study (``cliport-reproduce``): train agents over tasks, demo counts, recipes and seeds,
evaluate every checkpoint, and compare with the papers' tables.

A cell is one (task, agent, recipe, n_demos, seed) run: training, then validation and test of its checkpoints.
The cells run one after another here or as Ray tasks on a cluster (:mod:`cliport.study.cluster`), each exactly
once and resumable (:mod:`cliport.study.cells`); :mod:`cliport.study.report` turns their summaries into each
task's table and plot and the table over tasks; :mod:`cliport.study.status` reads a study folder's progress.
"""

from cliport.study.config import Cell, StudyConfig, expand_tasks, study_groups
from cliport.study.driver import run_study
from cliport.study.report import SCORES, combine_seeds, combined_table, markdown_table, plot_study, summarise_run

__all__ = [
    "SCORES",
    "Cell",
    "StudyConfig",
    "combine_seeds",
    "combined_table",
    "expand_tasks",
    "markdown_table",
    "plot_study",
    "run_study",
    "study_groups",
    "summarise_run",
]
