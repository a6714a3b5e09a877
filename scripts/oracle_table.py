"""Summarise the recorded oracle checks (``docs/oracle/*.jsonl``) as a markdown table.

Usage: python scripts/oracle_table.py                      (print the table)
       python scripts/oracle_table.py --readme docs/tasks.md   (rewrite the table between its markers)
       python scripts/oracle_table.py --blind --dir docs/oracle/blind --readme docs/results/blind-ceilings.md \
           --json cliport/published/blind_ceilings.json     (the language-blind ceilings, see below)

Each file holds one JSON line per seed, written by ``scripts/oracle_check.py --record-dir docs/oracle``.
Rows are per task and mode; a seed recorded twice counts once, with its latest result. The table shows
the seeds actually recorded (a task that has not reached 100 seeds says so), the success rate, the
failed seeds and the commits the records came from.

With ``--blind`` the records are the language-blind expert's (``oracle_check.py --blind``): the table gives each
task's mean score with its 95% interval and the episodes solved, beside CLIPort's Transporter-only column
(Table 1, 100 and 1000 demos), between the markers ``<!-- blind-table:start -->`` and ``<!-- blind-table:end -->``;
``--json`` also writes the scores for ``cliport-reproduce``'s ceiling column.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import sys

from oracle_check import iter_records  # scripts/ is on sys.path when this file runs

from cliport.data.seeds import episode_seeds
from cliport.evaluation.evaluate import confidence_interval
from cliport.evaluation.published import published_results, published_task_name

START = "<!-- oracle-table:start -->"
END = "<!-- oracle-table:end -->"
BLIND_START = "<!-- blind-table:start -->"
BLIND_END = "<!-- blind-table:end -->"


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


def blind_scores(groups: dict[tuple[str, str, float], dict[int, dict]]) -> dict[str, dict]:
    """Per task: the blind expert's mean score (x100), its interval, episodes, solved, mode and commits."""
    out = {}
    for (task, mode, scale), by_seed in sorted(groups.items()):
        records = [by_seed[s] for s in sorted(by_seed)]
        scores = [100 * r["total_reward"] for r in records]
        mean, (low, high) = statistics.mean(scores), confidence_interval(scores)
        out[task] = {
            "score": round(mean, 1),
            "interval": [round(low, 1), round(high, 1)],
            "episodes": len(records),
            "solved": sum(bool(r["success"]) for r in records),
            "mode": mode,
            "camera_scale": scale,
            "seeds": seed_span(sorted(by_seed), mode),
            "commits": sorted({str(r.get("commit")) for r in records}),
        }
    return out


def blind_table(scores: dict[str, dict]) -> str:
    """The ceilings beside CLIPort's Transporter-only scores (Table 1, test, 100 and 1000 demos)."""
    table1 = published_results()["cliport_table1_test"]
    lines = [
        "| task | episodes | blind ceiling [95% CI] | solved | CLIPort Transporter-only, 100 demos | 1000 demos |",
        "|---|---|---|---|---|---|",
    ]
    for task, row in scores.items():
        published = table1.get(published_task_name(task), {}).get("transporter_only", {})
        low, high = row["interval"]
        lines.append(
            f"| {task} | {row['episodes']} ({row['mode']}) | **{row['score']:.1f}** [{low:.1f}-{high:.1f}] "
            f"| {row['solved']}/{row['episodes']} | {published.get('100', '-')} | {published.get('1000', '-')} |"
        )
    return "\n".join(lines)


def write_json(path: str, scores: dict[str, dict], command: str) -> None:
    """The ceilings as ``cliport-reproduce`` reads them (``cliport/published/blind_ceilings.json``), atomically."""
    data = {
        "_about": "Language-blind ceilings: the mean score (total reward x100) of the scripted expert that never "
        "reads the instruction (Task.blind_plan), per task, with its 95% interval; docs/results/blind-ceilings.md.",
        "command": command,
        "tasks": scores,
    }
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def replace_between_markers(text: str, body: str, start: str = START, end: str = END) -> str:
    if start not in text or end not in text:
        raise ValueError(f"the markers {start} and {end} are missing")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{body}\n{end}{tail}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default="docs/oracle", help="folder of per-task JSON-lines records")
    parser.add_argument("--readme", help="rewrite the table between its markers in this file")
    parser.add_argument("--blind", action="store_true", help="the records are the language-blind expert's")
    parser.add_argument("--json", metavar="PATH", help="with --blind: also write the ceilings as JSON here")
    args = parser.parse_args()
    if args.json and not args.blind:
        sys.exit("error: --json goes with --blind")
    groups = load(args.dir)
    if not groups:
        sys.exit(f"error: no oracle records in {args.dir} (run scripts/oracle_check.py --record-dir {args.dir})")
    markers = (START, END)
    if args.blind:
        scores = blind_scores(groups)
        body, markers = blind_table(scores), (BLIND_START, BLIND_END)
        if args.json:
            command = f"python scripts/oracle_check.py --blind --task TASK --mode test --record-dir {args.dir}"
            write_json(args.json, scores, command)
    else:
        body = table(groups)
    if args.readme is None:
        print(body)
        return
    with open(args.readme) as f:
        text = f.read()
    try:
        text = replace_between_markers(text, body, *markers)
    except ValueError as e:
        sys.exit(f"error: {args.readme}: {e}")
    tmp = f"{args.readme}.tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, args.readme)
    print(f"wrote {len(groups)} rows to {args.readme}")


if __name__ == "__main__":
    main()
