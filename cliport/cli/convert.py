"""cliport-convert: a checkpoint of the reference CLIPort code as a cliport run folder.

See :mod:`cliport.train.convert` and docs/parity.md ("Coming from the reference CLIPort").
"""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import OneLineParser, run_cli


def _parser() -> argparse.ArgumentParser:
    from cliport.train.convert import REFERENCE_N_ROTATIONS, SUPPORTED

    parser = OneLineParser(
        prog="cliport-convert",
        description="Convert a checkpoint written by the reference CLIPort code (a PyTorch Lightning .ckpt, e.g. "
        "multi-language-conditioned-cliport-n1000-train/checkpoints/steps=400000-*.ckpt) into a run folder that "
        "cliport-eval, cliport-predict, cliport-push and cliport-train --resume use like a native one. Nothing in "
        "the file is run: it is read with a restricted unpickler. Prints a JSON summary.",
    )
    parser.add_argument("--from", dest="src", required=True, metavar="CKPT", help="the reference checkpoint")
    parser.add_argument("--run-dir", required=True, help="the run folder to write (must not hold a run)")
    parser.add_argument(
        "--agent-type",
        choices=sorted(SUPPORTED),
        help="the reference's agent name (default: detected from the checkpoint's weights)",
    )
    parser.add_argument(
        "--task", help="the run's task or group (default: from the reference's folder name {task}-{agent}-n{N}-train)"
    )
    parser.add_argument(
        "--n-rotations",
        type=int,
        default=REFERENCE_N_ROTATIONS,
        help=f"place rotations the checkpoint was trained with (not stored in it; the reference's configs: "
        f"{REFERENCE_N_ROTATIONS})",
    )
    parser.add_argument(
        "--clip-weights",
        default="openai",
        help="where the run loads CLIP from: openai (default), a weights file, or 'checkpoint' to write the "
        "checkpoint's own copy into the run folder; it must equal the checkpoint's CLIP",
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    from cliport.errors import ConfigError
    from cliport.train.convert import convert_checkpoint

    if args.n_rotations < 1:
        raise ConfigError(f"--n-rotations must be >= 1, got {args.n_rotations}")
    summary = convert_checkpoint(
        args.src, args.run_dir, args.agent_type, args.task, n_rotations=args.n_rotations, clip_weights=args.clip_weights
    )
    print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
