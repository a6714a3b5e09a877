"""Plot and tabulate what the training recipes do to learning, from `cliport-reproduce` study folders.

Each STUDY folder holds the `results.json` that `cliport-reproduce --recipes ...` writes. One panel per
study (task): validation (dashed) and test (solid) mean score against training steps, a colour per recipe,
thin lines for single training seeds and a thick line for their mean. The markdown table (stdout) gives
each recipe's per-seed scores at every checkpoint.

    python scripts/recipe_curves.py STUDY [STUDY ...] --out docs/recipes/recipe_curves.png
"""

from __future__ import annotations

import os
import statistics
from typing import Any

from cliport.cli.common import OneLineParser, run_cli
from cliport.errors import UserError
from cliport.utils.files import read_json

RECIPE_COLOURS = {"cliport": "C3", "ravens": "C0", "legacy": "C2"}


def load_study(folder: str) -> dict[str, Any]:
    path = os.path.join(folder, "results.json")
    if not os.path.isfile(path):
        raise UserError(f"{folder}: no results.json (run cliport-reproduce there first)")
    return read_json(path)


def _mean(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.mean(known) if known else None


def markdown_rows(study: dict[str, Any]) -> list[str]:
    """One table row per (agent, recipe, demos, seed) of a study: val / test at each checkpoint."""
    rows = []
    for run in study["runs"]:
        for seed_run in run["per_seed"]:
            cells = " / ".join(f"{c['step']}: {_fmt(c['val'])} / {_fmt(c['test'])}" for c in seed_run["checkpoints"])
            rows.append(
                f"| {study['task']} | {run['agent']} | {run.get('recipe') or '-'} | {run['n_demos']} "
                f"| {seed_run.get('seed', '-')} | {cells} |"
            )
    return rows


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def plot(studies: list[dict[str, Any]], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(studies), figsize=(5.0 * len(studies), 4.0), squeeze=False)
    for ax, study in zip(axes[0], studies, strict=True):
        for run in study["runs"]:
            recipe = run.get("recipe") or "-"
            colour = RECIPE_COLOURS.get(recipe, "C7")
            for key, style in (("test", "-"), ("val", "--")):
                for seed_run in run["per_seed"]:
                    points = [(c["step"], c[key]) for c in seed_run["checkpoints"] if c[key] is not None]
                    if points:
                        ax.plot(*zip(*points, strict=True), style, color=colour, alpha=0.35, linewidth=1)
                steps = sorted({c["step"] for s in run["per_seed"] for c in s["checkpoints"]})
                means = [
                    _mean([c[key] for s in run["per_seed"] for c in s["checkpoints"] if c["step"] == step])
                    for step in steps
                ]
                points = [(s, m) for s, m in zip(steps, means, strict=True) if m is not None]
                if points:
                    label = f"{recipe} {key} (mean of {len(run['per_seed'])} seed(s))"
                    ax.plot(*zip(*points, strict=True), style, marker="o", color=colour, linewidth=2.5, label=label)
        ax.set_title(f"{study['task']} ({study['runs'][0]['agent']}, {study['runs'][0]['n_demos']} demos)")
        ax.set_xlabel("training steps")
        ax.set_ylabel("mean score x100 (solid: test, dashed: val)")
        ax.set_ylim(-3, 103)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("studies", nargs="+", help="cliport-reproduce output folders (each with results.json)")
    parser.add_argument("--out", default="recipe_curves.png", help="the figure's path (PNG)")
    args = parser.parse_args(argv)
    studies = [load_study(folder) for folder in args.studies]
    plot(studies, args.out)
    print("| task | agent | recipe | demos | seed | val / test at each checkpoint |")
    print("|---|---|---|---|---|---|")
    for study in studies:
        print("\n".join(markdown_rows(study)))
    print(f"\nfigure: {args.out}")


if __name__ == "__main__":
    run_cli(main)
