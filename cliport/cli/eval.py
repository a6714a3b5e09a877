"""cliport-eval: evaluate a trained agent, or try a free-form instruction and see its heatmaps."""

from __future__ import annotations

import argparse
import json
import os

from cliport.cli.common import UserError, run_cli
from cliport.utils.config import read_defaults


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    d = read_defaults("eval")
    parser = argparse.ArgumentParser(
        prog="cliport-eval",
        description="Evaluate checkpoints of a training run on val/test episodes, or run one episode with "
        "--lang and save a video and the pick/place heatmaps.",
    )
    parser.add_argument("--run-dir", required=True, help="a cliport-train run folder")
    parser.add_argument("--checkpoint", default=d["checkpoint"], help="best | last | STEP | all")
    parser.add_argument("--task", help="default: the run's task")
    parser.add_argument("--mode", default=d["mode"], choices=["val", "test"])
    parser.add_argument("--n-episodes", type=int, default=d["n_episodes"])
    parser.add_argument("--agent", help="expected agent of the checkpoint (checked)")
    parser.add_argument("--lang", help="one episode with this instruction instead of the task's own")
    parser.add_argument("--seed", type=int, help="with --lang: the scene's seed (default: first seed of --mode)")
    parser.add_argument("--video", action="store_true", help="record a GIF of every evaluation episode")
    parser.add_argument("--out", help="output folder (default: RUN/eval)")
    parser.add_argument("--device", default=d["device"])
    parser.add_argument("--camera-scale", type=float, default=d["camera_scale"])
    parser.add_argument("--clip-weights", help="load CLIP from here instead of the recorded source")
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def checkpoints_to_run(run_dir: str, which: str) -> list[int | str]:
    from cliport.train.trainer import checkpoint_file, saved_checkpoint_steps

    steps = saved_checkpoint_steps(run_dir)
    if not steps and not os.path.exists(checkpoint_file(run_dir, "last")):
        raise UserError(f"no checkpoints in {run_dir}/checkpoints")
    if which == "all":
        return list(steps)
    if which == "last":
        return ["last"]
    if which == "best":
        path = os.path.join(run_dir, "val.json")
        if not os.path.exists(path):
            raise UserError(
                f"no validation results in {run_dir} (val.json) to pick the best checkpoint: use "
                "--checkpoint last|STEP, or train with --val-episodes > 0"
            )
        with open(path) as f:
            return [int(json.load(f)["best_step"])]
    if not which.isdigit() or int(which) not in steps:
        raise UserError(f"--checkpoint must be best, last, all or one of the saved steps {steps}, got {which!r}")
    return [int(which)]


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from cliport.agents import load_agent
    from cliport.data.seeds import episode_seeds
    from cliport.evaluation.evaluate import evaluate, resolve_device, write_json
    from cliport.train.trainer import checkpoint_file, load_run_config

    if not os.path.isdir(args.run_dir):
        raise UserError(f"run folder not found: {args.run_dir}")
    if args.lang is not None and not args.lang.strip():
        raise UserError("--lang must be a non-empty instruction")
    if args.n_episodes < 1:
        raise UserError(f"--n-episodes must be >= 1, got {args.n_episodes}")
    run = load_run_config(args.run_dir)
    task = args.task or run.task
    from cliport import tasks

    names = tasks.resolve(task)
    out = args.out or os.path.join(args.run_dir, "eval")
    device = resolve_device(args.device)
    for which in checkpoints_to_run(args.run_dir, args.checkpoint):
        path = checkpoint_file(args.run_dir, which)
        agent = load_agent(path, device=device, clip_weights=args.clip_weights)
        if args.agent is not None and agent.name != args.agent:
            raise UserError(f"{path} is a checkpoint of agent {agent.name!r}, not {args.agent!r}")
        if args.lang is not None:
            from cliport.evaluation.free_form import run_instruction

            seed = args.seed if args.seed is not None else episode_seeds(args.mode, 1)[0]
            result = run_instruction(agent, names[0], args.mode, seed, args.lang, out, args.camera_scale)
            print(json.dumps(result, indent=2))
            return
        for name in names:
            video_dir = os.path.join(out, "videos") if args.video else None
            result = evaluate(
                agent, name, args.mode, args.n_episodes, args.camera_scale, not args.no_progress, video_dir
            )
            result.update(
                checkpoint=which,
                checkpoint_file=path,
                agent=agent.name,
                clip_weights=agent.clip_source(),
                run_dir=args.run_dir,
            )
            write_json(os.path.join(out, f"{name}-{args.mode}-{which}.json"), result)
            summary = {k: v for k, v in result.items() if k != "episodes"}
            print(json.dumps(summary))


def entry() -> None:
    from cliport.train.trainer import TrainError

    run_cli(main, user_errors=(KeyError, ValueError, TrainError, FileNotFoundError))


if __name__ == "__main__":
    entry()
