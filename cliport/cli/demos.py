"""cliport-demos: generate oracle demonstrations for a task into a compact, resumable dataset.

The settings flags are the fields of ``cliport.data.generate.DemoConfig`` (defaults in configs/demos.toml).
"""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import OneLineParser, run_cli


def _shard(text: str) -> tuple[int, int]:
    try:
        i, k = (int(x) for x in text.split("/"))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--shard must look like I/K (e.g. 0/4), got {text!r}") from e
    if not (k >= 1 and 0 <= i < k):
        raise argparse.ArgumentTypeError(f"--shard I/K needs 0 <= I < K, got {text!r}")
    return i, k


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.data.generate import DemoConfig
    from cliport.utils.config import add_flags

    parser = OneLineParser(prog="cliport-demos", description=__doc__.split(":", 1)[1].strip())
    parser.add_argument("--task", required=True, help="task name (cliport-tasks lists them) or multi-task group")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument("--n", type=int, required=True, help="number of successful episodes")
    parser.add_argument("--shard", type=_shard, default=(0, 1), help="I/K: generate this machine's share")
    dests = add_flags(parser, [DemoConfig])
    parser.add_argument("--no-progress", action="store_true")
    return parser, dests


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    from cliport import tasks
    from cliport.data.generate import DemoConfig, generate
    from cliport.utils.config import given_flags, load

    config = load(DemoConfig, "demos", given_flags(args, dests))
    for name in tasks.resolve(args.task):
        summary = generate(name, args.mode, args.n, config, shard=args.shard, progress=not args.no_progress)
        print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
