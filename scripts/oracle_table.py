"""Summarise the recorded oracle checks (``docs/oracle/*.jsonl``) as a markdown table.

Usage: python scripts/oracle_table.py                      (print the table)
       python scripts/oracle_table.py --readme docs/tasks.md   (rewrite the table between its markers)

Each file holds one JSON line per seed, written by ``scripts/oracle_check.py --record-dir docs/oracle``.
Rows are per task and mode; a seed recorded twice counts once, with its latest result. The table shows
the seeds actually recorded (a task that has not reached 100 seeds says so), the success rate, the
failed seeds and the commits the records came from.
"""

from __future__ import annotations

import argparse
import glob
import os
import statistics
import sys

from oracle_check import iter_records  # scripts/ is on sys.path when this file runs

from cliport.data.seeds import episode_seeds

START = "<!-- oracle-table:start -->"
END = "<!-- oracle-table:end -->"


def load(folder: str) -> dict[tuple[str, str, float], dict[int, dict]]:
    """Latest record per seed, grouped by (task, mode, camera scale)."""
    groups: dict[tuple[str, str, float], dict[int, dict]] = {}
    for path in sorted(glob.glob(os.path.join(folder, "*.jsonl"))):
        for r in iter_records(path):
            groups.setdefault((r["task"], r["mode"], r["camera_scale"]), {})[int(r["seed"])] = r
    return groups


def table(groups: dict[tuple[str, str, float], dict[int, dict]]) -> str:
    lines = [
        "| task | mode | seeds | success | mean reward | s/episode | failed seeds (reward) | commits |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (task, mode, scale), by_seed in sorted(groups.items()):
        records = [by_seed[s] for s in sorted(by_seed)]
        n = len(records)
        ok = sum(bool(r["success"]) for r in records)
        failed = ", ".join(f"{r['seed']} ({r['total_reward']:.2f})" for r in records if not r["success"]) or "-"
        commits = ", ".join(sorted({str(r.get("commit")) for r in records}))
        mode_cell = mode if scale == 1.0 else f"{mode}, cameras x{scale:g}"
        lines.append(
            f"| {task} | {mode_cell} | {seed_span(sorted(by_seed), mode)} | {ok / n:.2f} ({ok}/{n}) "
            f"| {statistics.mean(r['total_reward'] for r in records):.3f} "
            f"| {statistics.mean(r['seconds'] for r in records):.1f} | {failed} | {commits} |"
        )
    return "\n".join(lines)


def seed_span(seeds: list[int], mode: str) -> str:
    """'first 100' when the seeds are exactly the protocol's first N of the mode, else the count and range."""
    if seeds == episode_seeds(mode, len(seeds)):
        return f"first {len(seeds)}"
    return f"{len(seeds)} in {seeds[0]}..{seeds[-1]}"


def replace_between_markers(text: str, body: str) -> str:
    if START not in text or END not in text:
        raise ValueError(f"the markers {START} and {END} are missing")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{START}\n{body}\n{END}{tail}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default="docs/oracle", help="folder of per-task JSON-lines records")
    parser.add_argument("--readme", help="rewrite the table between the oracle-table markers of this file")
    args = parser.parse_args()
    groups = load(args.dir)
    if not groups:
        sys.exit(f"error: no oracle records in {args.dir} (run scripts/oracle_check.py --record-dir {args.dir})")
    body = table(groups)
    if args.readme is None:
        print(body)
        return
    with open(args.readme) as f:
        text = f.read()
    try:
        text = replace_between_markers(text, body)
    except ValueError as e:
        sys.exit(f"error: {args.readme}: {e}")
    tmp = f"{args.readme}.tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, args.readme)
    print(f"wrote {len(groups)} rows to {args.readme}")


if __name__ == "__main__":
    main()
