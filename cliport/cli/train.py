"""cliport-train: train a two_stream (CLIPort) or transporter_only agent on demonstrations."""

from __future__ import annotations

import argparse
import json
import os

from cliport.cli.common import UserError, run_cli

AGENT_NAMES = ("two_stream", "transporter_only")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="cliport-train",
        description="Train an agent; defaults come from configs/train.toml. Checkpoints and metrics go to --run-dir.",
    )
    parser.add_argument("--agent", help="two_stream or transporter_only")
    parser.add_argument("--task", help="task name or multi-task group (cliport-tasks lists them)")
    parser.add_argument("--n-demos", type=int, help="training episodes per task")
    parser.add_argument("--n-steps", type=int, help="optimiser steps")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--lr", type=float, help="learning rate (default: the agent's)")
    parser.add_argument("--data-dir")
    parser.add_argument("--run-dir", help="default: runs/TASK-AGENT-nN-sSEED")
    parser.add_argument("--clip-weights", help="two_stream: 'openai', a local weights file, or 'random'")
    parser.add_argument("--device", help="auto, cpu, cuda, cuda:1 ...")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--resume", action="store_true", help="continue the run in --run-dir from its last save")
    parser.add_argument("--num-workers", type=int, help="DataLoader workers")
    parser.add_argument("--amp", choices=["auto", "bf16", "none"])
    parser.add_argument("--val-episodes", type=int, help="val episodes per checkpoint (0: skip validation)")
    parser.add_argument("--camera-scale", type=float, help="camera resolution of validation episodes")
    parser.add_argument("--checkpoint-steps", type=int, nargs="+", help="steps to save checkpoints at")
    parser.add_argument("--checkpoint-every", type=int)
    parser.add_argument("--log-every", type=int)
    parser.add_argument("--width", type=float, help="network width multiplier (1.0 = published size)")
    parser.add_argument(
        "--agent-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any agent config field, e.g. n_rotations=12 (repeatable)",
    )
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def _agent_options(args: argparse.Namespace) -> dict:
    import tomllib

    options = {}
    if args.width is not None:
        options["width"] = args.width
    for item in args.agent_option:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UserError(f"--agent-option must look like KEY=VALUE, got {item!r}")
        try:
            options[key] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            options[key] = value
    return options


def config_from_args(args: argparse.Namespace):
    from cliport.train.trainer import TrainConfig, load_run_config

    given = {
        "agent": args.agent,
        "task": args.task,
        "n_demos": args.n_demos,
        "n_steps": args.n_steps,
        "batch_size": args.batch_size,
        "lr": args.lr,
        "data_dir": args.data_dir,
        "run_dir": args.run_dir,
        "clip_weights": args.clip_weights,
        "device": args.device,
        "seed": args.seed,
        "num_workers": args.num_workers,
        "amp": args.amp,
        "val_episodes": args.val_episodes,
        "camera_scale": args.camera_scale,
        "checkpoint_steps": args.checkpoint_steps,
        "checkpoint_every": args.checkpoint_every,
        "log_every": args.log_every,
    }
    given = {k: v for k, v in given.items() if v is not None}
    if args.resume:
        if args.run_dir is None:
            raise UserError("--resume needs --run-dir (the run to continue)")
        saved = load_run_config(args.run_dir)
        if "agent" in given and given["agent"] != saved.agent:
            raise UserError(f"{args.run_dir} is a run of agent {saved.agent!r}, not {given['agent']!r}")
        values = {**saved.__dict__, **given}
        values["agent_overrides"] = {**saved.agent_overrides, **_agent_options(args)}
        return TrainConfig(**values)
    if "task" not in given:
        raise UserError("--task is required")
    config = TrainConfig.defaults(**given)
    config.agent_overrides.update(_agent_options(args))
    return config


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.agent is not None and args.agent not in AGENT_NAMES:
        raise UserError(f"unknown agent {args.agent!r}; choose one of: {', '.join(AGENT_NAMES)}")
    config = config_from_args(args)
    from cliport import tasks
    from cliport.train.trainer import train

    tasks.resolve(config.task)
    if config.n_steps < 1:
        raise UserError(f"--n-steps must be >= 1, got {config.n_steps}")
    if config.clip_weights not in (None, "openai", "random") and not os.path.exists(config.clip_weights):
        raise UserError(f"--clip-weights file not found: {config.clip_weights}")
    summary = train(config, resume=args.resume, progress=not args.no_progress)
    print(json.dumps(summary, indent=2))


def entry() -> None:
    from cliport.data.dataset import DatasetError
    from cliport.data.episode_io import EpisodeFileError

    run_cli(main, user_errors=(KeyError, ValueError, DatasetError, EpisodeFileError, FileNotFoundError))


if __name__ == "__main__":
    entry()
