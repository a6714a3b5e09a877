"""Quickstart: demos -> training -> evaluation -> pictures, end to end, in one command.

Generates oracle demonstrations of a task, trains a Transporter-only agent, evaluates it on test
seeds and saves a picture of its pick/place heatmaps and a GIF of one test episode. On a CUDA GPU it
trains the published network size; on a CPU it defaults to a narrow network and few steps so that it
finishes in minutes (expect a low score: it shows the pipeline, not the result; see README for the
real recipes). Everything goes to out/quickstart/; results.json sums it up.
"""

from __future__ import annotations

import argparse
import json
import os

import torch

from cliport.agents import load_agent
from cliport.data.generate import DemoConfig, generate
from cliport.evaluation.evaluate import evaluate
from cliport.evaluation.free_form import run_instruction
from cliport.train.trainer import TrainConfig, train


def main() -> None:
    gpu = torch.cuda.is_available()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--out", default="out/quickstart")
    parser.add_argument("--demos", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1000 if gpu else 60)
    parser.add_argument("--batch-size", type=int, default=8 if gpu else 2)
    parser.add_argument("--width", type=float, default=1.0 if gpu else 0.25, help="network width (1.0 = published)")
    parser.add_argument("--episodes", type=int, default=20 if gpu else 3, help="test episodes")
    parser.add_argument("--camera-scale", type=float, default=1.0 if gpu else 0.5)
    args = parser.parse_args()
    data_dir, run_dir = os.path.join(args.out, "data"), os.path.join(args.out, "run")

    print(f"1/4 demonstrations: {args.demos} oracle episodes of {args.task}")
    demos = generate(
        args.task, "train", args.demos, DemoConfig.defaults(data_dir=data_dir, camera_scale=args.camera_scale)
    )

    print(f"2/4 training transporter_only (width {args.width}) for {args.steps} steps")
    config = TrainConfig.defaults(
        agent="transporter_only",
        task=args.task,
        n_demos=args.demos,
        n_steps=args.steps,
        batch_size=args.batch_size,
        data_dir=data_dir,
        run_dir=run_dir,
        val_episodes=0,
        checkpoint_steps=[args.steps],
        camera_scale=args.camera_scale,
        num_workers=2,
    )
    config.agent_overrides["width"] = args.width
    resume = os.path.exists(os.path.join(run_dir, "checkpoints", "last.pt"))
    if not (resume and os.path.exists(os.path.join(run_dir, "checkpoints", f"step-{args.steps:06d}.pt"))):
        train(config, resume=resume)

    print(f"3/4 evaluating on {args.episodes} test episodes")
    agent = load_agent(os.path.join(run_dir, "checkpoints", "last.pt"))
    result = evaluate(agent, args.task, "test", args.episodes, camera_scale=args.camera_scale)

    print("4/4 a test episode with its heatmaps and a video")
    rollout = run_instruction(
        agent, args.task, "test", 10001, agent_instruction(args.task), args.out, args.camera_scale
    )
    summary = {
        "task": args.task,
        "demos": {k: demos[k] for k in ("saved", "skipped_existing", "demos_per_minute", "mb_per_step")},
        "training": {"steps": args.steps, "width": args.width, "batch_size": args.batch_size, "run_dir": run_dir},
        "test": {k: result[k] for k in ("n_episodes", "mean_score", "ci95", "success_rate")},
        "heatmaps": rollout["heatmaps"],
        "video": rollout["video"],
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(json.dumps(summary, indent=2))


def agent_instruction(task: str) -> str:
    from cliport import tasks

    return tasks.make(task).lang_template or "solve the task"


if __name__ == "__main__":
    main()
