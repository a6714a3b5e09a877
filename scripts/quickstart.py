"""Quickstart: demos -> training -> evaluation -> pictures, end to end, in one command.

On a CUDA GPU it trains a Transporter-only agent at the published size on place-red-in-green (10 demos,
600 steps) and reports how many test episodes it solves: a run that learns. On a CPU it runs the same
pipeline as a smoke run (narrow network, a few steps: it shows the pipeline, not learning) and prints
the command of the learning run with the time it takes on a CPU. Everything goes to out/quickstart/;
results.json sums it up.
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
from cliport.train.config import TrainConfig
from cliport.train.trainer import train
from cliport.utils.files import write_json

TASK = "place-red-in-green"
# Measured on the 2-core development machine (README, "What a CPU can and cannot show").
CPU_LEARNING_RUN = """\
  cliport-demos --task place-red-in-green --mode train --n 10
  cliport-train --agent transporter_only --task place-red-in-green --n-demos 10 --n-steps 1000 --batch-size 1 \\
    --width 0.25 --val-episodes 20 --checkpoint-steps 250 500 1000 --run-dir runs/prg-to-n10-w025
  cliport-eval --run-dir runs/prg-to-n10-w025 --checkpoint best --mode test --n-episodes 100"""


def main() -> None:
    gpu = torch.cuda.is_available()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default=TASK)
    parser.add_argument("--out", default="out/quickstart")
    parser.add_argument("--demos", type=int, default=10 if gpu else 4)
    parser.add_argument("--steps", type=int, default=600 if gpu else 30)
    parser.add_argument("--batch-size", type=int, default=1 if gpu else 2)
    parser.add_argument("--width", type=float, default=1.0 if gpu else 0.25, help="network width (1.0 = published)")
    parser.add_argument("--episodes", type=int, default=20 if gpu else 2, help="test episodes")
    parser.add_argument("--camera-scale", type=float, default=1.0 if gpu else 0.5)
    args = parser.parse_args()
    data_dir, run_dir = os.path.join(args.out, "data"), os.path.join(args.out, "run")
    smoke = not gpu and args.steps < 250
    if smoke:
        print("CPU found: this is a smoke run of the whole pipeline (a narrow net, a few steps); expect a low score.")

    print(f"1/4 demonstrations: {args.demos} oracle episodes of {args.task}")
    demos = generate(
        args.task, "train", args.demos, DemoConfig.defaults(data_dir=data_dir, camera_scale=args.camera_scale)
    )

    print(f"2/4 training transporter_only (width {args.width}, batch {args.batch_size}) for {args.steps} steps")
    config = TrainConfig.build(
        {
            "agent": "transporter_only",
            "task": args.task,
            "n_demos": args.demos,
            "n_steps": args.steps,
            "batch_size": args.batch_size,
            "data_dir": data_dir,
            "run_dir": run_dir,
            "val_episodes": 0,
            "checkpoint_steps": [args.steps],
            "num_workers": 2,
            "agent_config": {"width": args.width},
            "env": {"camera_scale": args.camera_scale},
        }
    )
    last = os.path.join(run_dir, "checkpoints", "last.pt")
    finished = os.path.exists(os.path.join(run_dir, "checkpoints", f"step-{args.steps:06d}.pt"))
    if not finished:
        train(config, resume=os.path.exists(os.path.join(run_dir, "config.json")))

    print(f"3/4 evaluating on {args.episodes} test episodes")
    agent = load_agent(last)
    result = evaluate(agent, args.task, "test", args.episodes, camera_scale=args.camera_scale)
    solved = round(result["success_rate"] * result["n_episodes"])

    print("4/4 a test episode with its heatmaps and a video")
    rollout = run_instruction(
        agent, args.task, "test", 10001, agent_instruction(args.task), args.out, args.camera_scale
    )
    summary = {
        "task": args.task,
        "device": "cuda" if gpu else "cpu",
        "smoke_run": smoke,
        "demos": {k: demos[k] for k in ("saved", "skipped_existing", "demos_per_minute", "mb_per_step")},
        "training": {"steps": args.steps, "width": args.width, "batch_size": args.batch_size, "run_dir": run_dir},
        "test": {k: result[k] for k in ("n_episodes", "mean_score", "ci95", "success_rate", "success_ci95")},
        "heatmaps": rollout["heatmaps"],
        "video": rollout["video"],
    }
    write_json(os.path.join(args.out, "results.json"), summary)
    print(json.dumps(summary, indent=2))
    print(f"\nThe agent solved {solved} of {result['n_episodes']} test episodes of {args.task}.")
    if smoke:
        print(
            "That was a smoke run: it shows the pipeline, not learning. The run below learns: on the 2-core\n"
            "development CPU its best checkpoint (500 steps, 34 minutes with one core free; ~1.7 s per step with\n"
            "both) solved 100 of 100 test episodes. With a GPU, this script trains at the published size instead.\n"
            + CPU_LEARNING_RUN
        )


def agent_instruction(task: str) -> str:
    from cliport import tasks

    return tasks.make(task).lang_template or "solve the task"


if __name__ == "__main__":
    main()
