"""Look up the papers' published scores for our agents and task names."""

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

# (table, column, training steps behind the number, protocol) per our agent.
_SOURCES = {
    "transporter_only": [
        ("transporter_paper_test", "transporter", 40000, "Transporter Networks paper, test, best of 1k-40k ckpts"),
        ("cliport_table6_val_ravens", "transporter", 200000, "CLIPort Table 6, validation"),
        ("cliport_table1_test", "transporter_only", 200000, "CLIPort Table 1, test, ckpt chosen on val"),
    ],
    "two_stream": [
        ("cliport_table6_val_ravens", "cliport_wo_lang", 200000, "CLIPort Table 6 (no language), validation"),
        ("cliport_table1_test", "cliport_single", 200000, "CLIPort Table 1, test, ckpt chosen on val"),
    ],
}


@cache
def published_results() -> dict[str, Any]:
    """The published tables (see the file's ``_about``)."""
    text = resources.files("cliport.reference").joinpath("published_results.json").read_text()
    return json.loads(text)


def published_scores(task: str, agent: str, n_demos: int) -> list[dict[str, Any]]:
    """Published scores (x100) of ``agent`` on ``task`` with ``n_demos`` demos, one per source."""
    data = published_results()
    out = []
    for table, column, steps, label in _SOURCES.get(agent, []):
        name = _CLIPORT_NAMES.get(task, task) if table == "cliport_table1_test" else task
        value = data.get(table, {}).get(name, {}).get(column, {}).get(str(n_demos))
        if value is not None:
            out.append({"source": label, "score": float(value), "training_steps": steps})
    return out
