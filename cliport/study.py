"""The reproduction study: train agents over demo counts, evaluate every checkpoint, compare with the papers.

For each (agent, n_demos): demos are generated (or reused), a run is trained (or resumed), every
scheduled checkpoint is validated (val episodes) and tested (test episodes). The report shows, per
run, the test score of the checkpoint chosen on validation (CLIPort's protocol), of the last
checkpoint, and the best test score over checkpoints (the optimistic choice), beside the published
numbers, and a plot of test success against training steps: how much of the gap between the two
papers' Transporter numbers comes from training length and checkpoint choice.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
from typing import Any

from cliport.errors import ConfigError
from cliport.evaluation.published import TABLE_RECIPES, paper_recipes, published_scores
from cliport.train.config import TrainConfig
from cliport.utils.config import read_defaults
from cliport.utils.files import read_json, write_json
from cliport.utils.run_dir import RunDir


@dataclasses.dataclass
class StudyConfig:
    """A reproduction study (``cliport-reproduce``).

    Args:
        task: task to study.
        agents: registered agent names to train.
        n_demos: demo counts, one run per (agent, count).
        n_steps: training steps of every run.
        out: study folder (runs, evaluations, table, plot).
        data_dir: folder of the demonstrations.
        val_episodes: val episodes per checkpoint (checkpoint selection).
        test_episodes: test episodes per checkpoint.
        batch_size: training batch size (None: configs/train.toml's).
        device: auto, cpu, cuda, ... (None: configs/train.toml's).
        seed: training seed (when seeds is empty).
        seeds: training seeds: one run per (agent, demos, seed), reported as mean and standard deviation
            over seeds (the CLIPort authors advise 3 or more); empty = [seed].
        camera_scale: camera resolution of the demos and of every evaluation episode.
        demo_workers: parallel simulators for demo generation.
        recipes: training recipes (configs/recipes.toml), one run per (agent, demos, recipe, seed); empty = each
            agent's papers' recipes (transporter_only: ravens and cliport; the CLIPort agents: cliport), so that
            every published column is compared with a run trained as that paper's code trains.
        agent_config: agent settings (e.g. {"width": 0.25, "clip_weights": "random"}); each run takes the keys
            its agent has, and a key no studied agent has is an error.
        checkpoint_steps: checkpoint steps (None: configs/train.toml's).
        eval_workers: simulator processes for validation and test episodes (None: the usable CPU cores,
            at most 8 and at most the episodes of one checkpoint).
    """

    agents: list[str]
    n_demos: list[int]
    n_steps: int
    out: str
    data_dir: str
    task: str = ""
    val_episodes: int = 100
    test_episodes: int = 100
    batch_size: int | None = None
    device: str | None = None
    seed: int = 0
    seeds: list[int] = dataclasses.field(default_factory=list)
    camera_scale: float = 1.0
    demo_workers: int = 1
    agent_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    recipes: list[str] = dataclasses.field(default_factory=list)
    checkpoint_steps: list[int] | None = None
    eval_workers: int | None = None

    def training_seeds(self) -> list[int]:
        return sorted(set(self.seeds)) or [self.seed]

    def agent_recipes(self, agent: str) -> list[str]:
        """The recipes ``agent`` trains with in this study."""
        return list(self.recipes) or paper_recipes(agent) or [read_defaults("train")["recipe"]]

    def train_config(self, agent: str, n_demos: int, seed: int | None = None, recipe: str | None = None) -> TrainConfig:
        """The train config of the (agent, n_demos, recipe, seed) run (its folder names the recipe, and the seed
        when there are several)."""
        seed = self.seed if seed is None else seed
        recipe = recipe or self.agent_recipes(agent)[0]
        suffix = f"-s{seed}" if len(self.training_seeds()) > 1 else ""
        from cliport.agents import agent_class

        fields = {f.name for f in dataclasses.fields(agent_class(agent).config_class)}
        studied = {f.name for a in self.agents for f in dataclasses.fields(agent_class(a).config_class)}
        unknown = sorted(set(self.agent_config) - studied)
        if unknown:
            raise ConfigError(f"no studied agent has the setting(s) {', '.join(unknown)}")
        given = {
            "agent": agent,
            "task": self.task,
            "n_demos": n_demos,
            "n_steps": self.n_steps,
            "data_dir": self.data_dir,
            "run_dir": os.path.join(self.out, "runs", f"{agent}-{recipe}-n{n_demos}{suffix}"),
            "recipe": recipe,
            "seed": seed,
            "val_episodes": self.val_episodes,
            "batch_size": self.batch_size,
            "device": self.device,
            "checkpoint_steps": self.checkpoint_steps,
            "agent_config": {k: v for k, v in self.agent_config.items() if k in fields},
            "env": {"camera_scale": self.camera_scale},
        }
        return TrainConfig.build({k: v for k, v in given.items() if v is not None})


def run_study(config: StudyConfig, progress: bool = True) -> dict[str, Any]:
    """Run (or resume) every part of the study and write results.json, table.md and the plot."""
    from cliport.agents import load_agent
    from cliport.data.generate import DemoConfig, generate
    from cliport.evaluation.engine import resolve_workers
    from cliport.evaluation.evaluate import evaluate
    from cliport.evaluation.validation import make_validator, validate_run
    from cliport.train.trainer import train
    from cliport.utils.device import resolve_device

    train_configs = {
        (a, recipe, n, seed): config.train_config(a, n, seed, recipe)
        for a in config.agents
        for recipe in config.agent_recipes(a)
        for n in config.n_demos
        for seed in config.training_seeds()
    }
    test_workers = resolve_workers(config.eval_workers, config.test_episodes, "--eval-workers")
    val_workers = None
    if config.val_episodes > 0:
        val_workers = resolve_workers(config.eval_workers, config.val_episodes, "--eval-workers")
    os.makedirs(config.out, exist_ok=True)
    write_json(os.path.join(config.out, "study_config.json"), dataclasses.asdict(config))
    demo_config = DemoConfig.defaults(
        data_dir=config.data_dir, workers=config.demo_workers, camera_scale=config.camera_scale
    )
    generate(config.task, "train", max(config.n_demos), demo_config, progress=progress)
    per_seed: dict[tuple[str, str, int], list[dict[str, Any]]] = {}
    for (agent_name, recipe, n, seed), train_config in train_configs.items():
        run = RunDir(train_config.resolved_run_dir())
        device = resolve_device(train_config.device)
        validate = config.val_episodes > 0
        if run.checkpoint_steps()[-1:] != [config.n_steps]:
            validator = None
            if validate:
                validator = make_validator(
                    train_config.val_mode,
                    device,
                    run_dir=run.root,
                    task=config.task,
                    n_episodes=config.val_episodes,
                    camera_scale=config.camera_scale,
                    progress=progress,
                    workers=val_workers,
                )
            train(train_config, resume=run.is_run(), progress=progress, validator=validator)
        elif validate:
            validate_run(
                run.root, config.task, config.val_episodes, config.camera_scale, device, None, progress, val_workers
            )
        test: dict[str, float] = {}
        for step in run.checkpoint_steps():
            path = os.path.join(run.eval_dir, f"{config.task}-test-{step}.json")
            if not os.path.exists(path):
                agent = load_agent(run.checkpoint(step), device)
                result = evaluate(
                    agent,
                    config.task,
                    "test",
                    config.test_episodes,
                    config.camera_scale,
                    progress,
                    workers=test_workers,
                )
                result.update(
                    checkpoint=step, agent=agent_name, recipe=recipe, weight_sources=agent.weight_source_values()
                )
                write_json(path, result)
            test[str(step)] = read_json(path)["mean_score"]
        val = read_json(run.val) if os.path.exists(run.val) else {"checkpoints": {}}
        summary = summarise_run(config.task, agent_name, n, test, val, recipe)
        per_seed.setdefault((agent_name, recipe, n), []).append({**summary, "seed": seed})
    runs = [combine_seeds(group) for group in per_seed.values()]
    results = {"task": config.task, "n_steps": config.n_steps, "seeds": config.training_seeds(), "runs": runs}
    write_json(os.path.join(config.out, "results.json"), results)
    with open(os.path.join(config.out, "table.md"), "w") as f:
        f.write(markdown_table(results))
    plot_study(results, os.path.join(config.out, "success_vs_steps.png"))
    return results


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
    ax.set_xscale("log")
    ax.set_xlabel("training steps")
    ax.set_ylabel("test success (mean reward x100)")
    ax.set_ylim(-3, 103)
    ax.set_title(f"{results['task']}: ours (lines) vs published (open markers)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
