"""Quickstart: demos -> training -> evaluation -> pictures, end to end, in one command, with an agent that learns.

On a CPU it trains the Transporter agent at an eighth of the published width on place-red-in-green: 10
demos, one place rotation (the task's bowls are round, so the expert's place yaw carries no information;
see ``Task.place_yaw_informative``), 400 steps at batch 1, then evaluates 20 test episodes in parallel
simulators: about 4 minutes on 2 cores (the choices and what each trades are in docs/quickstart.md). On a CUDA GPU
it trains at the published width instead. Defaults: ``configs/quickstart.toml``. Either way it saves the
heatmaps and a GIF of a test episode the agent solved. Everything goes to out/quickstart/; results.json
sums it up, and ``tensorboard --logdir out/quickstart`` shows the training curves and the test score. Run it
again and it resumes: finished demos and training are kept.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from typing import Any

import torch

from cliport import tasks
from cliport.agents import load_agent
from cliport.cli.common import OneLineParser, run_cli
from cliport.data.generate import DemoConfig, generate
from cliport.errors import ConfigError, RunDirError
from cliport.evaluation.evaluate import evaluate
from cliport.evaluation.free_form import run_instruction
from cliport.train.config import TrainConfig
from cliport.train.recipes import recipe_names
from cliport.train.trainer import load_run_config, train
from cliport.utils.config import read_defaults
from cliport.utils.files import write_json
from cliport.utils.tensorboard import log_result, summary_writer

AGENT = "transporter_only"


def parse_args(device: str) -> Any:
    defaults = read_defaults("quickstart")
    per_device = defaults[device]
    parser = OneLineParser(prog="quickstart.py", description=__doc__.splitlines()[0])
    parser.add_argument("--task", default=defaults["task"])
    parser.add_argument("--out", default="out/quickstart", help="output folder (demos, run, pictures, results.json)")
    parser.add_argument("--demos", type=int, default=defaults["demos"], help="oracle demonstrations to train on")
    parser.add_argument("--steps", type=int, default=per_device["steps"], help="training steps")
    parser.add_argument("--batch-size", type=int, default=defaults["batch_size"])
    parser.add_argument("--width", type=float, default=per_device["width"], help="network width (1.0 = published)")
    parser.add_argument(
        "--n-rotations", type=int, help="place rotations (default: 1 where the task's place yaw says nothing, else 36)"
    )
    parser.add_argument("--episodes", type=int, default=defaults["episodes"], help="test episodes")
    parser.add_argument("--camera-scale", type=float, default=per_device["camera_scale"])
    parser.add_argument("--seed", type=int, default=0, help="training seed")
    parser.add_argument(
        "--recipe", default=defaults["recipe"], choices=recipe_names(), help="training recipe (configs/recipes.toml)"
    )
    args = parser.parse_args()
    for name in ("demos", "steps", "batch_size", "episodes"):
        if getattr(args, name) < 1:
            raise ConfigError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    tasks.resolve(args.task)
    return args


def train_config(args: Any, data_dir: str, run_dir: str, n_rotations: int) -> TrainConfig:
    config = TrainConfig.build(
        {
            "agent": AGENT,
            "recipe": args.recipe,
            "task": args.task,
            "n_demos": args.demos,
            "n_steps": args.steps,
            "batch_size": args.batch_size,
            "data_dir": data_dir,
            "run_dir": run_dir,
            "seed": args.seed,
            "val_episodes": 0,
            "checkpoint_steps": [args.steps],
            "num_workers": 1,
            "agent_config": {"width": args.width, "n_rotations": n_rotations},
            "env": {"camera_scale": args.camera_scale},
        }
    )
    if os.path.exists(os.path.join(run_dir, "config.json")):
        saved = load_run_config(run_dir).to_dict()
        changed = sorted(k for k, v in config.to_dict().items() if saved.get(k) != v)
        if changed:
            raise RunDirError(
                f"{run_dir} holds a quickstart run with other settings ({', '.join(changed)}): "
                "pass another --out, or delete that folder"
            )
    return config


def main() -> None:
    device = "cuda" if torch.cuda.is_available() else "cpu"
    args = parse_args(device)
    n_rotations = args.n_rotations or (36 if tasks.place_yaw_informative(args.task) else 1)
    data_dir, run_dir = os.path.join(args.out, "data"), os.path.join(args.out, "run")
    config = train_config(args, data_dir, run_dir, n_rotations)
    timings: dict[str, float] = {}
    start = time.perf_counter()

    print(f"1/4 demonstrations: {args.demos} oracle episodes of {args.task}")
    demos = generate(
        args.task, "train", args.demos, DemoConfig.defaults(data_dir=data_dir, camera_scale=args.camera_scale)
    )
    timings["demos_s"] = time.perf_counter() - start

    print(
        f"2/4 training {AGENT} on {device} with the {args.recipe} recipe (width {args.width}, "
        f"{n_rotations} place rotation(s), batch {args.batch_size}) for {args.steps} steps"
    )
    last = os.path.join(run_dir, "checkpoints", "last.pt")
    mark = time.perf_counter()
    if not os.path.exists(os.path.join(run_dir, "checkpoints", f"step-{args.steps:06d}.pt")):
        train(config, resume=os.path.exists(os.path.join(run_dir, "config.json")))
    timings["training_s"] = time.perf_counter() - mark

    print(f"3/4 evaluating on {args.episodes} test episodes")
    mark = time.perf_counter()
    agent = load_agent(last, device=device)
    result = evaluate(agent, args.task, "test", args.episodes, camera_scale=args.camera_scale)
    solved = [row for row in result["episodes"] if row["total_reward"] > 0.99]
    timings["evaluation_s"] = time.perf_counter() - mark
    with contextlib.closing(summary_writer(os.path.join(run_dir, "eval", "tensorboard"))) as tensorboard:
        log_result(tensorboard, f"eval/{args.task}/test", result, args.steps)  # beside training's curves

    seed = solved[0]["seed"] if solved else result["episodes"][0]["seed"]
    print(f"4/4 heatmaps and a GIF of test episode {seed}" + ("" if solved else " (none was solved)"))
    mark = time.perf_counter()
    instruction = tasks.make(args.task).lang_template or "solve the task"
    rollout = run_instruction(agent, args.task, "test", seed, instruction, args.out, args.camera_scale)
    timings["pictures_s"] = time.perf_counter() - mark
    timings["total_s"] = time.perf_counter() - start
    summary = {
        "task": args.task,
        "device": device,
        "demos": {k: demos[k] for k in ("saved", "skipped_existing", "demos_per_minute", "mb_per_step")},
        "training": {
            "agent": AGENT,
            "recipe": args.recipe,
            "steps": args.steps,
            "width": args.width,
            "n_rotations": n_rotations,
            "batch_size": args.batch_size,
            "seed": args.seed,
            "run_dir": run_dir,
        },
        "test": {k: result[k] for k in ("n_episodes", "mean_score", "ci95", "success_rate", "success_ci95")},
        "solved": len(solved),
        "gif_episode": {"seed": seed, "task_reward": rollout["task_reward"], "solved": bool(solved)},
        "heatmaps": rollout["heatmaps"],
        "video": rollout["video"],
        "seconds": {k: round(v, 1) for k, v in timings.items()},
    }
    write_json(os.path.join(args.out, "results.json"), summary)
    print(json.dumps(summary, indent=2))
    low, high = result["success_ci95"]
    print(
        f"\nThe agent solved {len(solved)} of {result['n_episodes']} test episodes of {args.task} "
        f"(success 95% interval {low:.0f}-{high:.0f} %; {timings['total_s'] / 60:.1f} minutes).\n"
        f"Watch episode {seed}: {rollout['video']}\nIts heatmaps: {', '.join(rollout['heatmaps'])}"
    )


if __name__ == "__main__":
    run_cli(main)
