"""The study's results: one run's scores, the rows over seeds, a task's table and plot, the table over tasks.

For each cell the report keeps the test score of the checkpoint chosen on validation (CLIPort's protocol), of
the last checkpoint, and the best test score over checkpoints (the optimistic choice), beside the published
numbers; the plot shows test success against training steps: how much of the gap between the two papers'
Transporter numbers comes from training length and checkpoint choice. Where a task's instruction changes what must
be done, its language-blind ceiling (the best score of an agent that ignores the instruction) is shown beside the
scores, and a plain Ravens task and the sequenced task built on it are reported side by side.
"""

from __future__ import annotations

import io
import os
import statistics
from typing import Any

from cliport.evaluation.published import PLAIN_TASKS, TABLE_RECIPES, blind_ceiling, published_scores
from cliport.utils.files import write_bytes, write_json, write_text


def summarise_run(
    task: str, agent: str, n_demos: int, test: dict[str, float], val: dict[str, Any], recipe: str | None = None
) -> dict[str, Any]:
    """One run's scores: per checkpoint (val, test), val-selected, last, best-on-test, and the published scores
    of the papers whose code trains with ``recipe`` (all of them without one)."""
    steps = sorted(int(s) for s in test)
    published = [p for p in published_scores(task, agent, n_demos) if recipe in (None, TABLE_RECIPES[p["table"]])]
    val_scores = {int(s): v["mean_score"] for s, v in val.get("checkpoints", {}).items()}
    selected = val.get("best_step")
    return {
        "agent": agent,
        "recipe": recipe,
        "n_demos": n_demos,
        "checkpoints": [{"step": s, "val": val_scores.get(s), "test": test[str(s)]} for s in steps],
        "val_selected_step": selected,
        "test_at_val_selected": test.get(str(selected)) if selected is not None else None,
        "test_at_last": test[str(steps[-1])] if steps else None,
        "best_test": max(test.values()) if test else None,
        "published": published,
    }


SCORES = ("test_at_val_selected", "test_at_last", "best_test")


def _mean_std(values: list[float | None]) -> tuple[float | None, float | None]:
    known = [v for v in values if v is not None]
    if not known:
        return None, None
    mean = statistics.mean(known)
    return round(mean, 2), (round(statistics.stdev(known), 2) if len(known) > 1 else None)


def combine_seeds(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One row of the study from the runs of one (agent, demos) cell over training seeds: every score is
    the mean over seeds with its sample standard deviation in ``<key>_std`` (None for one seed); each
    seed's own summary stays under ``per_seed``."""
    first = runs[0]
    row: dict[str, Any] = {
        "agent": first["agent"],
        "recipe": first.get("recipe"),
        "n_demos": first["n_demos"],
        "seeds": [r.get("seed") for r in runs],
        "published": first["published"],
        "per_seed": runs,
    }
    for key in SCORES:
        row[key], row[f"{key}_std"] = _mean_std([r[key] for r in runs])
    selected = [r["val_selected_step"] for r in runs]
    row["val_selected_step"] = selected[0] if len(runs) == 1 else selected
    steps = sorted({c["step"] for r in runs for c in r["checkpoints"]})
    row["checkpoints"] = []
    for step in steps:
        cells = [c for r in runs for c in r["checkpoints"] if c["step"] == step]
        val, val_std = _mean_std([c["val"] for c in cells])
        test, test_std = _mean_std([c["test"] for c in cells])
        row["checkpoints"].append({"step": step, "val": val, "test": test, "val_std": val_std, "test_std": test_std})
    return row


def markdown_table(results: dict[str, Any]) -> str:
    lines = [
        f"# Reproduction study: {results['task']} ({results['n_steps']} training steps)",
        "",
        "Scores are mean total reward x100 on test episodes.",
        "",
        "| agent | recipe | demos | test @ val-selected ckpt | test @ last | best test over ckpts | published |",
        "|---|---|---|---|---|---|---|",
    ]

    def fmt(v: float | None, std: float | None = None) -> str:
        return "-" if v is None else f"{v:.1f}" + ("" if std is None else f" ± {std:.1f}")

    seeds = results.get("seeds", [])
    if len(seeds) > 1:
        lines.insert(3, f"Mean ± standard deviation over {len(seeds)} training seeds ({', '.join(map(str, seeds))}).")
    ceiling = blind_ceiling(results["task"])
    if ceiling is not None:
        lines.insert(3, f"{ceiling_text(ceiling)}.\n")
    for r in results["runs"]:
        published = "; ".join(f"{p['score']:.1f} ({p['source']})" for p in r["published"]) or "-"
        selected = fmt(r["test_at_val_selected"], r.get("test_at_val_selected_std"))
        chosen = r["val_selected_step"]
        if isinstance(chosen, list) and any(c is not None for c in chosen):
            selected += f" (steps {', '.join(str(c) for c in chosen)})"
        elif isinstance(chosen, int):
            selected += f" (step {chosen})"
        elif r["test_at_val_selected"] is None:
            selected += " (no validation)"
        last, best = fmt(r["test_at_last"], r.get("test_at_last_std")), fmt(r["best_test"], r.get("best_test_std"))
        recipe = r.get("recipe") or "-"
        lines.append(f"| {r['agent']} | {recipe} | {r['n_demos']} | {selected} | {last} | {best} | {published} |")
    lines += ["", "Per checkpoint (val / test):", ""]
    for r in results["runs"]:
        cells = ", ".join(
            f"{c['step']}: {fmt(c['val'], c.get('val_std'))} / {fmt(c['test'], c.get('test_std'))}"
            for c in r["checkpoints"]
        )
        lines.append(f"- {r['agent']} ({r.get('recipe') or '-'}), {r['n_demos']} demos: {cells}")
    return "\n".join(lines) + "\n"


def ceiling_text(ceiling: dict[str, Any]) -> str:
    """One line on a language-blind ceiling, e.g. 'Language-blind ceiling: 47.9 [44.1-51.7] (100 test episodes)'."""
    low, high = ceiling["interval"]
    return (
        f"Language-blind ceiling: {ceiling['score']:.1f} [{low:.1f}-{high:.1f}] ({ceiling['episodes']} test episodes "
        "of the expert that never reads the instruction; docs/results/blind-ceilings.md)"
    )


def plot_study(results: dict[str, Any], path: str) -> None:
    """Test success against training steps per run, with published numbers at their training length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    markers = {"Transporter": "s", "CLIPort": "^"}
    for i, r in enumerate(results["runs"]):
        color = f"C{i % 10}"
        xs = [c["step"] for c in r["checkpoints"]]
        ys = [c["test"] for c in r["checkpoints"]]
        n_seeds = len(r.get("seeds") or [None])
        recipe = f" ({r['recipe']} recipe)" if r.get("recipe") else ""
        label = f"ours: {r['agent']}{recipe}, {r['n_demos']} demos" + (
            f", mean of {n_seeds} seeds" if n_seeds > 1 else ""
        )
        ax.plot(xs, ys, "o-", color=color, label=label)
        stds = [c.get("test_std") for c in r["checkpoints"]]
        if any(s is not None for s in stds):
            low = [y - (s or 0.0) for y, s in zip(ys, stds, strict=True)]
            high = [y + (s or 0.0) for y, s in zip(ys, stds, strict=True)]
            ax.fill_between(xs, low, high, color=color, alpha=0.15, linewidth=0)
        for p in r["published"]:
            marker = markers["Transporter" if p["source"].startswith("Transporter") else "CLIPort"]
            ax.plot([p["training_steps"]], [p["score"]], marker, color=color, markersize=9, fillstyle="none")
            ax.annotate(p["source"].split(",")[0], (p["training_steps"], p["score"]), fontsize=6, color=color,
                        xytext=(4, -3), textcoords="offset points")  # fmt: skip
    ceiling = blind_ceiling(results["task"])
    if ceiling is not None:
        ax.axhline(ceiling["score"], color="0.3", linestyle=":", label="language-blind ceiling")
    ax.set_xscale("log")
    ax.set_xlabel("training steps")
    ax.set_ylabel("test success (mean reward x100)")
    ax.set_ylim(-3, 103)
    ax.set_title(f"{results['task']}: ours (lines) vs published (open markers)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    image = io.BytesIO()
    fig.savefig(image, format="png", dpi=120)
    write_bytes(path, image.getvalue())
    plt.close(fig)


def task_results(task: str, n_steps: int, seeds: list[int], summaries: list[dict[str, Any]]) -> dict[str, Any]:
    """A task's results.json content from its cells' summaries (:func:`summarise_run` plus ``seed``), in the
    study's cell order: one row per (agent, recipe, demos), over seeds."""
    per_row: dict[tuple[str, str | None, int], list[dict[str, Any]]] = {}
    for summary in summaries:
        per_row.setdefault((summary["agent"], summary["recipe"], summary["n_demos"]), []).append(summary)
    runs = [combine_seeds(group) for group in per_row.values()]
    return {"task": task, "n_steps": n_steps, "seeds": seeds, "runs": runs}


def write_task_results(folder: str, results: dict[str, Any]) -> None:
    """``results.json``, ``table.md`` and ``success_vs_steps.png`` of one task, each written atomically."""
    write_json(os.path.join(folder, "results.json"), results)
    write_text(os.path.join(folder, "table.md"), markdown_table(results))
    plot_study(results, os.path.join(folder, "success_vs_steps.png"))


def row_score(row: dict[str, Any]) -> tuple[float | None, float | None, str]:
    """The score a row stands for in summaries: the test score at the val-selected checkpoint (CLIPort's
    protocol), or at the last checkpoint without validation; with its standard deviation and which it is."""
    if row.get("test_at_val_selected") is not None:
        return row["test_at_val_selected"], row.get("test_at_val_selected_std"), "val-selected"
    return row.get("test_at_last"), row.get("test_at_last_std"), "last"


def combined_table(all_results: list[dict[str, Any]]) -> str:
    """One table per (agent, recipe) over the studied tasks: a column per demo count, each cell ours (at the
    val-selected checkpoint, or the last without validation) beside the published score of that recipe's paper."""
    blocks: dict[tuple[str, str | None], dict[str, dict[int, dict[str, Any]]]] = {}
    demo_counts: set[int] = set()
    for results in all_results:
        for row in results["runs"]:
            blocks.setdefault((row["agent"], row.get("recipe")), {}).setdefault(results["task"], {})
            blocks[(row["agent"], row.get("recipe"))][results["task"]][row["n_demos"]] = row
            demo_counts.add(row["n_demos"])
    counts = sorted(demo_counts)
    steps = sorted({r["n_steps"] for r in all_results})
    seeds = sorted({s for r in all_results for s in r.get("seeds", [])})
    lines = [
        f"# Reproduction study over {len(all_results)} task(s) ({', '.join(map(str, steps))} training steps, "
        f"seed(s) {', '.join(map(str, seeds))})",
        "",
        "Each cell: ours / published (mean total reward x100 on test episodes). Ours is the test score of the",
        "checkpoint chosen on validation (marked * where a run had no validation: its last checkpoint), the mean",
        "over seeds ± their standard deviation; published is the score of the paper whose code trains with the",
        "row's recipe (- where that paper has none; CLIPort's Table 6, beside the cliport recipe's Transporter, is on",
        "validation episodes). Each task's table.md names every source and has every checkpoint.",
    ]

    def fmt(row: dict[str, Any] | None) -> str:
        if row is None:
            return "not run"
        value, std, which = row_score(row)
        ours = "-" if value is None else f"{value:.1f}" + ("" if std is None else f" ± {std:.1f}")
        ours += "*" if which == "last" else ""
        published = "; ".join(f"{p['score']:.1f}" for p in row["published"]) or "-"
        return f"{ours} / {published}"

    def ceiling(task: str) -> str:
        found = blind_ceiling(task)
        return "-" if found is None else f"{found['score']:.1f}"

    with_ceiling = any(blind_ceiling(r["task"]) is not None for r in all_results)
    if with_ceiling:
        lines[-1] += (
            " The blind ceiling is the best an agent that ignores the instruction can score (- where the instruction "
            "does not change what must be done; docs/results/blind-ceilings.md)."
        )
    for (agent, recipe), tasks in blocks.items():
        lines += ["", f"## {agent}, {recipe or '-'} recipe", ""]
        demos = " | ".join(f"{n} demo{'s' if n != 1 else ''}" for n in counts)
        lines.append(f"| task | {'blind ceiling | ' if with_ceiling else ''}{demos} |")
        lines.append("|---|" + ("---|" if with_ceiling else "") + "---|" * len(counts))
        for task, rows in tasks.items():
            first = f"| {task} | " + (f"{ceiling(task)} | " if with_ceiling else "")
            lines.append(first + " | ".join(fmt(rows.get(n)) for n in counts) + " |")
    pairs = task_pairs([r["task"] for r in all_results])
    if pairs:
        lines += [
            "",
            "## Plain and sequenced tasks side by side",
            "",
            "Ours on the plain Ravens task and on the instruction-following task built on it, same agent, recipe",
            "and demos; the sequenced task's blind ceiling beside them.",
            "",
            "| agent | recipe | demos | plain task | plain | sequenced task | sequenced | its blind ceiling |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for plain, seq in pairs:
            for (agent, recipe), tasks in blocks.items():
                for n in counts:
                    a, b = tasks.get(plain, {}).get(n), tasks.get(seq, {}).get(n)
                    if a is None and b is None:
                        continue
                    lines.append(
                        f"| {agent} | {recipe or '-'} | {n} | {plain} | {fmt(a).split(' / ')[0]} | {seq} "
                        f"| {fmt(b).split(' / ')[0]} | {ceiling(seq)} |"
                    )
    return "\n".join(lines) + "\n"


def task_pairs(tasks: list[str]) -> list[tuple[str, str]]:
    """(plain task, sequenced task) for every sequenced task in ``tasks`` whose plain task is there too."""
    return [(PLAIN_TASKS[t], t) for t in tasks if t in PLAIN_TASKS and PLAIN_TASKS[t] in tasks]


def plot_pairs(all_results: list[dict[str, Any]], path: str) -> bool:
    """Test success against training steps on each plain task and the sequenced task built on it (one panel per
    pair), every run of both, with the sequenced task's language-blind ceiling as a line. False (nothing
    written) when no pair was studied."""
    by_task = {r["task"]: r for r in all_results}
    pairs = task_pairs(list(by_task))
    if not pairs:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(pairs), figsize=(7.5 * len(pairs), 4.5), squeeze=False)
    for ax, (plain, seq) in zip(axes[0], pairs, strict=True):
        k = 0
        for task, style in ((plain, "o-"), (seq, "s--")):
            for r in by_task[task]["runs"]:
                xs = [c["step"] for c in r["checkpoints"]]
                ys = [c["test"] for c in r["checkpoints"]]
                recipe = f", {r['recipe']}" if r.get("recipe") else ""
                ax.plot(xs, ys, style, color=f"C{k % 10}", label=f"{task}: {r['agent']}{recipe}, {r['n_demos']} demos")
                k += 1
        ceiling = blind_ceiling(seq)
        if ceiling is not None:
            ax.axhline(ceiling["score"], color="0.3", linestyle=":", label=f"{seq}: language-blind ceiling")
        ax.set_xscale("log")
        ax.set_xlabel("training steps")
        ax.set_ylabel("test success (mean reward x100)")
        ax.set_ylim(-3, 103)
        ax.set_title(f"{plain} and {seq}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    image = io.BytesIO()
    fig.savefig(image, format="png", dpi=120)
    write_bytes(path, image.getvalue())
    plt.close(fig)
    return True


def write_combined(folder: str, all_results: list[dict[str, Any]]) -> None:
    """``combined.json`` (every task's results), ``combined.md`` (:func:`combined_table`) and, when a plain task and
    a sequenced one built on it were studied, ``plain_vs_sequenced.png`` (:func:`plot_pairs`), atomically."""
    write_json(os.path.join(folder, "combined.json"), {"tasks": all_results})
    write_text(os.path.join(folder, "combined.md"), combined_table(all_results))
    plot_pairs(all_results, os.path.join(folder, "plain_vs_sequenced.png"))
