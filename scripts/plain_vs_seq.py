"""Draw the plain-against-sequenced figure from one or more study folders.

Usage: python scripts/plain_vs_seq.py --studies STUDY [STUDY ...] --out plain_vs_sequenced.png

Each STUDY is a ``cliport-reproduce`` output folder (its ``combined.json``). The runs of every studied task are
gathered over the folders, so that cells studied apart (say transporter_only on assembling-kits and
assembling-kits-seq-seen-colors in one study, two_stream on the sequenced task in another) share one panel per
plain/sequenced pair, with the sequenced task's language-blind ceiling as a line (``cliport.study.report``).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from cliport.errors import UserError
from cliport.study.report import plot_pairs, task_pairs
from cliport.utils.files import read_json


def gather(folders: list[str]) -> list[dict[str, Any]]:
    """Every task's results over the study folders, the runs of a task studied in several folders together."""
    by_task: dict[str, dict[str, Any]] = {}
    for folder in folders:
        missing = f"{folder} has no combined.json: not a cliport-reproduce folder"
        for results in read_json(os.path.join(folder, "combined.json"), UserError, missing)["tasks"]:
            merged = by_task.setdefault(results["task"], {**results, "runs": []})
            merged["runs"] = merged["runs"] + results["runs"]
    return list(by_task.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="+", required=True, metavar="STUDY", help="cliport-reproduce folders")
    parser.add_argument("--out", required=True, help="the PNG to write")
    args = parser.parse_args()
    try:
        results = gather(args.studies)
    except UserError as e:
        sys.exit(f"error: {e}")
    if not plot_pairs(results, args.out):
        studied = ", ".join(sorted(r["task"] for r in results))
        sys.exit(f"error: no plain task studied beside a sequenced one built on it (studied: {studied})")
    print(f"wrote {args.out}: {', '.join(f'{a} / {b}' for a, b in task_pairs([r['task'] for r in results]))}")


if __name__ == "__main__":
    main()
