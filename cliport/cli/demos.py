"""cliport-demos: generate oracle demonstrations for a task into a compact, resumable dataset."""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import UserError, run_cli
from cliport.data.episode_io import EpisodeFileError
from cliport.data.generate import DemoConfig, GenerationError, generate


def _shard(text: str) -> tuple[int, int]:
    try:
        i, k = (int(x) for x in text.split("/"))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--shard must look like I/K (e.g. 0/4), got {text!r}") from e
    if not (k >= 1 and 0 <= i < k):
        raise argparse.ArgumentTypeError(f"--shard I/K needs 0 <= I < K, got {text!r}")
    return i, k


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    defaults = DemoConfig.defaults()
    parser = argparse.ArgumentParser(prog="cliport-demos", description=__doc__.split(":", 1)[1].strip())
    parser.add_argument("--task", required=True, help="task name (cliport-tasks lists them) or multi-task group")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument("--n", type=int, required=True, help="number of successful episodes")
    parser.add_argument("--workers", type=int, default=defaults.workers, help="parallel simulator processes")
    parser.add_argument("--data-dir", default=defaults.data_dir)
    parser.add_argument("--shard", type=_shard, default=(0, 1), help="I/K: generate this machine's share")
    parser.add_argument("--camera-scale", type=float, default=defaults.camera_scale)
    parser.add_argument("--raw-images", action="store_true", default=defaults.raw_images)
    parser.add_argument("--no-progress", action="store_true")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from cliport import tasks

    if args.n < 0:
        raise UserError(f"--n must be >= 0, got {args.n}")
    if args.workers < 1:
        raise UserError(f"--workers must be >= 1, got {args.workers}")
    config = DemoConfig.defaults(
        data_dir=args.data_dir, workers=args.workers, camera_scale=args.camera_scale, raw_images=args.raw_images
    )
    for name in tasks.resolve(args.task):
        summary = generate(name, args.mode, args.n, config, shard=args.shard, progress=not args.no_progress)
        print(json.dumps(summary))


def entry() -> None:
    run_cli(main, user_errors=(KeyError, ValueError, GenerationError, EpisodeFileError))


if __name__ == "__main__":
    entry()
