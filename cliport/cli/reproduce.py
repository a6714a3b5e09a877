"""cliport-reproduce: train agents over demo counts, evaluate every checkpoint, compare with the papers."""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import UserError, run_cli


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="cliport-reproduce", description=__doc__.split(":", 1)[1].strip())
    parser.add_argument("--task", required=True)
    parser.add_argument("--agents", nargs="+", default=["transporter_only", "two_stream"])
    parser.add_argument("--n-demos", type=int, nargs="+", default=[1, 10, 100, 1000])
    parser.add_argument("--n-steps", type=int, default=40000)
    parser.add_argument("--out", help="study folder (default: studies/TASK)")
    parser.add_argument("--data-dir", default="data")
    parser.add_argument("--val-episodes", type=int, default=100)
    parser.add_argument("--test-episodes", type=int, default=100)
    parser.add_argument("--checkpoint-steps", type=int, nargs="+")
    parser.add_argument("--batch-size", type=int)
    parser.add_argument("--device")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clip-weights")
    parser.add_argument("--camera-scale", type=float, default=1.0)
    parser.add_argument("--demo-workers", type=int, default=1)
    parser.add_argument("--width", type=float, help="network width multiplier (smoke tests)")
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from cliport import tasks
    from cliport.evaluation.study import StudyConfig, run_study

    tasks.resolve(args.task)
    for agent in args.agents:
        if agent not in ("transporter_only", "two_stream"):
            raise UserError(f"unknown agent {agent!r}; choose from transporter_only, two_stream")
    if min(args.n_demos) < 1 or args.n_steps < 1:
        raise UserError("--n-demos and --n-steps must be positive")
    config = StudyConfig(
        task=args.task,
        agents=args.agents,
        n_demos=sorted(set(args.n_demos)),
        n_steps=args.n_steps,
        out=args.out or f"studies/{args.task}",
        data_dir=args.data_dir,
        val_episodes=args.val_episodes,
        test_episodes=args.test_episodes,
        batch_size=args.batch_size,
        device=args.device,
        seed=args.seed,
        clip_weights=args.clip_weights,
        camera_scale=args.camera_scale,
        demo_workers=args.demo_workers,
        agent_overrides={} if args.width is None else {"width": args.width},
        checkpoint_steps=args.checkpoint_steps,
    )
    results = run_study(config, progress=not args.no_progress)
    print(json.dumps({"out": config.out, "runs": len(results["runs"])}))


def entry() -> None:
    from cliport.data.dataset import DatasetError

    run_cli(main, user_errors=(KeyError, ValueError, DatasetError, FileNotFoundError))


if __name__ == "__main__":
    entry()
