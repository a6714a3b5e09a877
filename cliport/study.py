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
import json
import os
from typing import Any

from cliport.evaluation.published import published_scores


@dataclasses.dataclass
class StudyConfig:
    task: str
    agents: list[str]
    n_demos: list[int]
    n_steps: int
    out: str
    data_dir: str
    val_episodes: int = 100
    test_episodes: int = 100
    batch_size: int | None = None
    device: str | None = None
    seed: int = 0
    clip_weights: str | None = None
    camera_scale: float = 1.0
    demo_workers: int = 1
    agent_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    checkpoint_steps: list[int] | None = None


def _load(path: str) -> Any:
    with open(path) as f:
        return json.load(f)


def run_study(config: StudyConfig, progress: bool = True) -> dict[str, Any]:
    """Run (or resume) every part of the study and write results.json, table.md and the plot."""
    from cliport.agents import load_agent
    from cliport.data.generate import DemoConfig, generate
    from cliport.evaluation.evaluate import evaluate, resolve_device, write_json
    from cliport.train import trainer

    os.makedirs(config.out, exist_ok=True)
    write_json(os.path.join(config.out, "study_config.json"), dataclasses.asdict(config))
    demo_config = DemoConfig.defaults(
        data_dir=config.data_dir, workers=config.demo_workers, camera_scale=config.camera_scale
    )
    generate(config.task, "train", max(config.n_demos), demo_config, progress=progress)
    device = resolve_device(config.device or "auto")
    runs = []
    for agent_name in config.agents:
        for n in config.n_demos:
            run_dir = os.path.join(config.out, "runs", f"{agent_name}-n{n}")
            overrides = {
                "agent": agent_name,
                "task": config.task,
                "n_demos": n,
                "n_steps": config.n_steps,
                "data_dir": config.data_dir,
                "run_dir": run_dir,
                "seed": config.seed,
                "val_episodes": config.val_episodes,
                "camera_scale": config.camera_scale,
                "batch_size": config.batch_size,
                "device": config.device,
                "clip_weights": config.clip_weights,
                "checkpoint_steps": config.checkpoint_steps,
            }
            train_config = trainer.TrainConfig.defaults(**overrides)
            train_config.agent_overrides.update(config.agent_overrides)
            last = trainer.checkpoint_file(run_dir, "last")
            finished = trainer.saved_checkpoint_steps(run_dir)[-1:] == [config.n_steps]
            if not finished:
                trainer.train(train_config, resume=os.path.exists(last), progress=progress)
            elif config.val_episodes > 0:
                trainer.validate(run_dir, train_config, device=device, progress=progress)
            test: dict[str, float] = {}
            for step in trainer.saved_checkpoint_steps(run_dir):
                path = os.path.join(run_dir, "eval", f"{config.task}-test-{step}.json")
                if not os.path.exists(path):
                    agent = load_agent(trainer.checkpoint_file(run_dir, step), device, config.clip_weights)
                    result = evaluate(agent, config.task, "test", config.test_episodes, config.camera_scale, progress)
                    result.update(checkpoint=step, agent=agent_name, clip_weights=agent.clip_source())
                    write_json(path, result)
                test[str(step)] = _load(path)["mean_score"]
            val_path = os.path.join(run_dir, "val.json")
            val = _load(val_path) if os.path.exists(val_path) else {"checkpoints": {}}
            runs.append(summarise_run(config.task, agent_name, n, test, val))
    results = {"task": config.task, "n_steps": config.n_steps, "runs": runs}
    write_json(os.path.join(config.out, "results.json"), results)
    with open(os.path.join(config.out, "table.md"), "w") as f:
        f.write(markdown_table(results))
    plot_study(results, os.path.join(config.out, "success_vs_steps.png"))
    return results


def summarise_run(task: str, agent: str, n_demos: int, test: dict[str, float], val: dict[str, Any]) -> dict[str, Any]:
    """One run's scores: per checkpoint (val, test), val-selected, last, best-on-test, published."""
    steps = sorted(int(s) for s in test)
    val_scores = {int(s): v["mean_score"] for s, v in val.get("checkpoints", {}).items()}
    selected = val.get("best_step")
    return {
        "agent": agent,
        "n_demos": n_demos,
        "checkpoints": [{"step": s, "val": val_scores.get(s), "test": test[str(s)]} for s in steps],
        "val_selected_step": selected,
        "test_at_val_selected": test.get(str(selected)) if selected is not None else None,
        "test_at_last": test[str(steps[-1])] if steps else None,
        "best_test": max(test.values()) if test else None,
        "published": published_scores(task, agent, n_demos),
    }


def markdown_table(results: dict[str, Any]) -> str:
    lines = [
        f"# Reproduction study: {results['task']} ({results['n_steps']} training steps)",
        "",
        "Scores are mean total reward x100 on test episodes.",
        "",
        "| agent | demos | test @ val-selected ckpt | test @ last | best test over ckpts | published |",
        "|---|---|---|---|---|---|",
    ]

    def fmt(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    for r in results["runs"]:
        published = "; ".join(f"{p['score']:.1f} ({p['source']})" for p in r["published"]) or "-"
        selected = fmt(r["test_at_val_selected"])
        if r["val_selected_step"] is not None:
            selected += f" (step {r['val_selected_step']})"
        last, best = fmt(r["test_at_last"]), fmt(r["best_test"])
        lines.append(f"| {r['agent']} | {r['n_demos']} | {selected} | {last} | {best} | {published} |")
    lines += ["", "Per checkpoint (val / test):", ""]
    for r in results["runs"]:
        cells = ", ".join(f"{c['step']}: {fmt(c['val'])} / {fmt(c['test'])}" for c in r["checkpoints"])
        lines.append(f"- {r['agent']}, {r['n_demos']} demos: {cells}")
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
        ax.plot(xs, ys, "o-", color=color, label=f"ours: {r['agent']}, {r['n_demos']} demos")
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
