"""Does pretraining buy colour transfer and data efficiency? The language lesson's agent with random against
pretrained CLIP weights of one architecture, at several demo counts, tested on seen and unseen colours.

Each cell runs ``scripts/quickstart.py --language`` (the lesson's settings: configs/quickstart.toml [language],
its time budget included) on put-one-block-in-bowl-seen-colors with ``--demos N``, ``--semantic-encoder NAME`` and
``--clip-weights`` random or the pretrained file, and ``--test-task put-one-block-in-bowl-unseen-colors``; then
writes one JSON line to ``OUT/grid.jsonl``: solved and swapped instructions followed on the seen colours, and on
the unseen split, all and only those naming an unseen colour. At the end ``OUT/grid.md`` tables every cell and
``OUT/demo_curve.png`` plots following and solving against demos. Cells share one demo folder (``OUT/demos``); a
re-run skips finished cells and resumes an interrupted one (the quickstart resumes). Arguments this script does
not know are passed to every quickstart run (``--minutes 5``, ``--episodes 40``, ...).

    python scripts/pretrain_experiment.py --weights out/pretrain/open_clip_model.safetensors --out out/pretrain-grid

The arm ``published`` (``--arms random pretrained published``) runs CLIPort's RN50 with its published weights
(``--clip-weights openai``): where they can be had (the Hugging Face cache, or network). The arm
``pretrained-maps`` is ``pretrained`` with ``--similarity-maps``: the encoder's dense image-text similarity to the
instruction and its phrases joins the semantic decoder's laterals; ``pretrained-maps-only`` also takes the sentence
out of the decoder's gates (``--no-language-gates``), so the instruction reaches the nets through the maps alone.
``pretrained-bank`` and ``pretrained-bank-only`` are those two with ``--similarity-bank``: each map the probability
of its text against the training instructions' phrases. ``pretrained-bank-dropout`` is ``pretrained-bank`` with
``--gate-phrase-dropout 0.5``: the gates' sentence loses half its phrases' colour words in training, and every
phrase the demos never showed at act time.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from typing import Any

from cliport.cli.common import OneLineParser, run_cli
from cliport.errors import ConfigError
from cliport.evaluation.evaluate import success_interval
from cliport.utils.files import read_json, write_bytes, write_text

TRAIN_TASK = "put-one-block-in-bowl-seen-colors"
TEST_TASK = "put-one-block-in-bowl-unseen-colors"
ARMS = (
    "random",
    "pretrained",
    "pretrained-maps",
    "pretrained-maps-only",
    "pretrained-bank",
    "pretrained-bank-only",
    "pretrained-bank-dropout",
    "published",
)
#: The similarity-map flags of each arm that trains on random or pretrained weights.
MAP_FLAGS = {
    "random": [],
    "pretrained": [],
    "pretrained-maps": ["--similarity-maps"],
    "pretrained-maps-only": ["--similarity-maps", "--no-language-gates"],
    "pretrained-bank": ["--similarity-maps", "--similarity-bank"],
    "pretrained-bank-only": ["--similarity-maps", "--similarity-bank", "--no-language-gates"],
    "pretrained-bank-dropout": ["--similarity-maps", "--similarity-bank", "--gate-phrase-dropout", "0.5"],
}
QUICKSTART = os.path.join(os.path.dirname(os.path.abspath(__file__)), "quickstart.py")


def parse_args() -> tuple[Any, list[str]]:
    parser = OneLineParser(prog="pretrain_experiment.py", description=__doc__.splitlines()[0])
    parser.add_argument("--weights", help="the pretrained encoder (cliport-pretrain's open_clip_model.safetensors)")
    parser.add_argument(
        "--semantic-encoder", help="its open_clip model (default: the one the weights file's metadata names)"
    )
    parser.add_argument("--arms", nargs="+", default=["random", "pretrained"], choices=ARMS)
    parser.add_argument("--demos", nargs="+", type=int, default=[10, 30, 100], help="demo counts of the curve")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="training seeds of each cell")
    parser.add_argument("--out", default="out/pretrain-grid", help="cells, shared demos and grid.jsonl")
    args, passthrough = parser.parse_known_args()
    if any(n < 1 for n in args.demos):
        raise ConfigError(f"--demos must all be at least 1, got {args.demos}")
    if any(arm.startswith("pretrained") for arm in args.arms):
        if not args.weights or not os.path.isfile(args.weights):
            raise ConfigError(f"the pretrained arm needs --weights FILE (from cliport-pretrain), got {args.weights}")
        if args.semantic_encoder is None:
            args.semantic_encoder = written_for(args.weights)
    if args.semantic_encoder is None and "random" in args.arms:
        raise ConfigError("the random arm needs --semantic-encoder NAME (or --weights, whose metadata names it)")
    return args, passthrough


def written_for(path: str) -> str:
    """The open_clip model a cliport-pretrain weights file holds (its metadata); ConfigError if it says none."""
    from cliport.models.encoders.clip_weights import MODEL_NAME_KEY
    from cliport.pretrain.checkpoint import read_open_clip_metadata

    name = read_open_clip_metadata(path).get(MODEL_NAME_KEY)
    if not name:
        raise ConfigError(f"{path} does not name its model (not written by cliport-pretrain): pass --semantic-encoder")
    return name


def arm_flags(arm: str, args: Any) -> list[str]:
    """The quickstart flags of an arm: the same architecture for random and pretrained, CLIPort's for published."""
    if arm == "published":
        return ["--clip-weights", "openai"]
    weights = "random" if arm == "random" else os.path.abspath(args.weights)
    return ["--clip-weights", weights, "--semantic-encoder", args.semantic_encoder, *MAP_FLAGS[arm]]


def cell_line(arm: str, n_demos: int, seed: int, results: dict[str, Any], seconds: float | None) -> dict[str, Any]:
    """One cell's JSON line from its quickstart results.json."""
    training = results["training"]
    following = results.get("instruction_following") or {}
    unseen = results["other_tests"][TEST_TASK]
    return {
        "arm": arm,
        "demos": n_demos,
        "seed": seed,
        "clip_weights": training["clip_weights"],
        "semantic_encoder": training.get("semantic_encoder"),
        "steps": training["steps"],
        "tested_step": training["tested_step"],
        "seen": {
            "task": results["task"],
            "solved": results["solved"],
            "episodes": results["test"]["n_episodes"],
            "followed": following.get("followed"),
            "swaps": following.get("n"),
        },
        "unseen": {
            k: unseen[k] for k in ("task", "test", "following", "unseen_named", "seen_named", "by_named", "scenes")
        },
        "minutes": round(results["seconds"]["total_s"] / 60, 1),
        "wall_minutes": None if seconds is None else round(seconds / 60, 1),
        "results": results["_path"],
        "environment": results.get("environment"),
    }


def write_grid(path: str, lines: dict[str, dict[str, Any]]) -> None:
    write_text(path, "".join(json.dumps(line) + "\n" for line in lines.values()))


def rate(part: dict[str, Any], key: str, of: str) -> float | None:
    """``part[key] / part[of]``, None where nothing was counted."""
    return part[key] / part[of] if part.get(of) else None


def grid_table(rows: list[dict[str, Any]]) -> str:
    """The cells as a markdown table: seen colours, and the unseen split's instructions naming an unseen colour."""
    lines = [
        "| arm | demos | seed | steps | seen: solved | seen: swaps followed | naming an unseen colour: solved | "
        "naming an unseen colour: swaps followed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        seen, named = row["seen"], row["unseen"]["unseen_named"]
        lines.append(
            f"| {row['arm']} | {row['demos']} | {row['seed']} | {row.get('steps', '-')} | "
            f"{seen['solved']}/{seen['episodes']} | {seen['followed']}/{seen['swaps']} | "
            f"{named['solved']}/{named['episodes']} | {named['followed']}/{named['swaps']} |"
        )
    return "\n".join(lines) + "\n"


def _counted(hits: int, n: int) -> str:
    """``hits/n (rate %, lo-hi)``: the Wilson 95 % interval of the pooled rate."""
    if not n:
        return "-"
    lo, hi = success_interval(hits, n)
    return f"{hits}/{n} ({100 * hits / n:.0f} %, {lo:.0f}-{hi:.0f})"


def pooled_table(rows: list[dict[str, Any]]) -> str:
    """Each arm and demo count pooled over its seeds, with 95 % intervals over the pooled episodes and swaps: seen
    colours, and on the unseen split the swaps naming an unseen block and those naming a seen one."""
    cells: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for row in rows:
        cells.setdefault((row["arm"], row["demos"]), []).append(row)
    lines = [
        "| arm | demos | seeds | seen: solved | seen: swaps followed | unseen split: swaps naming an unseen block "
        "followed | unseen split: swaps naming a seen block followed |",
        "|---|---|---|---|---|---|---|",
    ]
    for (arm, demos), group in cells.items():
        seen = {k: sum(row["seen"][k] or 0 for row in group) for k in ("solved", "episodes", "followed", "swaps")}
        by_block = {"unseen": [0, 0], "seen": [0, 0]}
        for row in group:
            for name, part in row["unseen"].get("by_named", {}).items():
                pooled = by_block["unseen" if name in ("block_unseen", "both_unseen") else "seen"]
                pooled[0] += part["followed"]
                pooled[1] += part["swaps"]
        lines.append(
            f"| {arm} | {demos} | {', '.join(str(row['seed']) for row in group)} | "
            f"{_counted(seen['solved'], seen['episodes'])} | {_counted(seen['followed'], seen['swaps'])} | "
            f"{_counted(*by_block['unseen'])} | {_counted(*by_block['seen'])} |"
        )
    return "\n".join(lines) + "\n"


def plot_curve(rows: list[dict[str, Any]], path: str) -> None:
    """Instructions followed and episodes solved against demos, one line per arm and colour split (the mean over
    seeds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    arms = sorted({row["arm"] for row in rows}, key=ARMS.index)
    demos = sorted({row["demos"] for row in rows})
    panels = (("followed", "swaps", "swapped instructions followed"), ("solved", "episodes", "episodes solved"))
    for ax, (key, of, title) in zip(axes, panels, strict=True):
        for k, arm in enumerate(arms):
            for split, style, label in (("seen", "o-", "seen colours"), ("unseen", "s--", "naming an unseen colour")):
                points: dict[int, list[float]] = {}
                for row in rows:
                    part = row["seen"] if split == "seen" else row["unseen"]["unseen_named"]
                    value = rate(part, key, of)
                    if row["arm"] == arm and value is not None:
                        points.setdefault(row["demos"], []).append(100 * value)
                xs = sorted(points)
                means = [sum(points[x]) / len(points[x]) for x in xs]
                ax.plot(xs, means, style, color=f"C{k}", label=f"{arm}: {label}")
        ax.set_xscale("log")
        ax.set_xticks(demos, [str(n) for n in demos])
        ax.set_xlabel("demonstrations (seen colours)")
        ax.set_ylabel("%")
        ax.set_ylim(-3, 103)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].axhline(100 / 3, color="0.4", linestyle=":", label="chance: one of three blocks")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    image = io.BytesIO()
    fig.savefig(image, format="png", dpi=110)
    write_bytes(path, image.getvalue())
    plt.close(fig)


def main() -> None:
    args, passthrough = parse_args()
    demos = os.path.abspath(os.path.join(args.out, "demos"))
    os.makedirs(demos, exist_ok=True)
    grid_path = os.path.join(args.out, "grid.jsonl")
    lines: dict[str, dict[str, Any]] = {}
    if os.path.exists(grid_path):
        with open(grid_path) as f:
            for row in (json.loads(text) for text in f if text.strip()):
                lines[f"{row['arm']}-n{row['demos']}-s{row['seed']}"] = row
    cells = [(arm, n, seed) for n in sorted(args.demos) for arm in args.arms for seed in args.seeds]
    for k, (arm, n_demos, seed) in enumerate(cells, 1):
        name = f"{arm}-n{n_demos}-s{seed}"
        if name in lines:
            print(f"[{k}/{len(cells)}] {name}: done before", flush=True)
            continue
        cell = os.path.join(args.out, "cells", name)
        os.makedirs(cell, exist_ok=True)
        if not os.path.lexists(os.path.join(cell, "data")):
            os.symlink(demos, os.path.join(cell, "data"))  # every cell reads the first N of the shared demos
        command = [sys.executable, QUICKSTART, "--language", "--task", TRAIN_TASK, "--test-task", TEST_TASK]
        command += ["--demos", str(n_demos), "--seed", str(seed), "--out", cell, *arm_flags(arm, args), *passthrough]
        print(f"[{k}/{len(cells)}] {name}: {' '.join(command[1:])}", flush=True)
        start = time.perf_counter()
        done = subprocess.run(command)
        if done.returncode != 0:
            raise SystemExit(f"error: cell {name} failed (exit status {done.returncode}); a re-run resumes it")
        results = {**read_json(os.path.join(cell, "results.json")), "_path": os.path.join(cell, "results.json")}
        lines[name] = cell_line(arm, n_demos, seed, results, time.perf_counter() - start)
        write_grid(grid_path, lines)
    for row in lines.values():
        seen, unseen = row["seen"], row["unseen"]["unseen_named"]
        print(
            f"{row['arm']:>10} n={row['demos']:<3} seed {row['seed']}: seen solved {seen['solved']}/"
            f"{seen['episodes']}, followed {seen['followed']}/{seen['swaps']}; naming unseen colours solved "
            f"{unseen['solved']}/{unseen['episodes']}, followed {unseen['followed']}/{unseen['swaps']}"
        )
    rows = sorted(lines.values(), key=lambda row: (row["demos"], ARMS.index(row["arm"]), row["seed"]))
    write_text(os.path.join(args.out, "grid.md"), grid_table(rows) + "\nPooled over seeds:\n\n" + pooled_table(rows))
    plot_curve(rows, os.path.join(args.out, "demo_curve.png"))
    print(
        f"one line per cell: {grid_path}; the table: {os.path.join(args.out, 'grid.md')}; the curve: "
        f"{os.path.join(args.out, 'demo_curve.png')}"
    )


if __name__ == "__main__":
    run_cli(main)
