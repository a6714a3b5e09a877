"""Look up the papers' published scores for our agents and task names, the measured language-blind ceilings of
the instruction-following tasks, and which plain task each sequenced one is built on."""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from typing import Any

# Our task names -> the names used in CLIPort's Table 1.
_CLIPORT_NAMES = {
    "packing-boxes-pairs-seen-colors": "packing-box-pairs-seen-colors",
    "packing-boxes-pairs-unseen-colors": "packing-box-pairs-unseen-colors",
    "put-block-in-bowl-seen-colors": "put-blocks-in-bowls-seen-colors",
    "put-block-in-bowl-unseen-colors": "put-blocks-in-bowls-unseen-colors",
    "packing-shapes": "packing-unseen-shapes",
    "packing-seen-objects-seq": "packing-seen-google-objects-seq",
    "packing-unseen-objects-seq": "packing-unseen-google-objects-seq",
    "packing-seen-objects-group": "packing-seen-google-objects-group",
    "packing-unseen-objects-group": "packing-unseen-google-objects-group",
}

# Per published table: the training steps behind its numbers and how they were measured. Which column
# belongs to which agent is the agent's own ``published_columns``.
TABLES = {
    "transporter_paper_test": (40000, "Transporter Networks paper, test, best of 1k-40k ckpts"),
    "cliport_table6_val_ravens": (200000, "CLIPort Table 6, validation"),
    "cliport_table1_test": (200000, "CLIPort Table 1, test, ckpt chosen on val"),
}


def published_task_name(task: str) -> str:
    """The name CLIPort's Table 1 gives our task ``task`` (most are the same)."""
    return _CLIPORT_NAMES.get(task, task)


@cache
def published_results() -> dict[str, Any]:
    """The published tables (see the file's ``_about``)."""
    text = resources.files("cliport.published").joinpath("published_results.json").read_text()
    return json.loads(text)


#: CLIPort's instruction-following tasks and the plain Ravens task each is built on: reported side by side.
PLAIN_TASKS = {
    "assembling-kits-seq-seen-colors": "assembling-kits",
    "assembling-kits-seq-unseen-colors": "assembling-kits",
    "stack-block-pyramid-seq-seen-colors": "stack-block-pyramid",
    "stack-block-pyramid-seq-unseen-colors": "stack-block-pyramid",
    "towers-of-hanoi-seq-seen-colors": "towers-of-hanoi",
    "towers-of-hanoi-seq-unseen-colors": "towers-of-hanoi",
    "packing-boxes-pairs-seen-colors": "packing-boxes",
    "packing-boxes-pairs-unseen-colors": "packing-boxes",
    "separating-piles-seen-colors": "sweeping-piles",
    "separating-piles-unseen-colors": "sweeping-piles",
    "align-rope": "manipulating-rope",
}


@cache
def blind_ceilings() -> dict[str, dict[str, Any]]:
    """Per task, the measured language-blind ceiling: ``score`` (mean total reward x100 of the expert that never
    reads the instruction), ``interval`` (95%), ``episodes``, ``solved``; empty where none is packaged
    (``cliport/published/blind_ceilings.json``, written by ``scripts/oracle_table.py --blind --json``)."""
    path = resources.files("cliport.published").joinpath("blind_ceilings.json")
    if not path.is_file():
        return {}
    return dict(json.loads(path.read_text())["tasks"])


def blind_ceiling(task: str) -> dict[str, Any] | None:
    """:func:`blind_ceilings` of ``task``, or None (a task whose instruction does not change what must be done,
    or one not measured)."""
    return blind_ceilings().get(task)


#: The training recipe (configs/recipes.toml) of the code behind each published table: Transporter Networks
#: trained with Ravens' code, every CLIPort table (its Transporter-only columns too) with CLIPort's.
TABLE_RECIPES = {
    "transporter_paper_test": "ravens",
    "cliport_table6_val_ravens": "cliport",
    "cliport_table1_test": "cliport",
}


def paper_recipes(agent: str) -> list[str]:
    """The recipes of the papers that publish ``agent``'s columns (e.g. transporter_only: ravens, cliport)."""
    from cliport.agents import agent_class

    recipes = {TABLE_RECIPES[table] for table in agent_class(agent).published_columns}
    return sorted(recipes, key=lambda r: list(TABLE_RECIPES.values()).index(r))


def published_scores(task: str, agent: str, n_demos: int) -> list[dict[str, Any]]:
    """Published scores (x100) of ``agent`` on ``task`` with ``n_demos`` demos, one per source."""
    from cliport.agents import agent_class

    data = published_results()
    out = []
    for table, column in agent_class(agent).published_columns.items():
        steps, label = TABLES[table]
        if table == "cliport_table6_val_ravens" and column == "cliport_wo_lang":
            label = "CLIPort Table 6 (no language), validation"
        name = published_task_name(task) if table == "cliport_table1_test" else task
        value = data.get(table, {}).get(name, {}).get(column, {}).get(str(n_demos))
        if value is not None:
            out.append({"source": label, "score": float(value), "training_steps": steps, "table": table})
    return out
