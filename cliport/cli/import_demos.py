"""cliport-import: convert real demonstrations (RGB-D views and pick/place poses), or a dataset written by
the reference CLIPort's / Ravens' demos.py, into demonstration files.

The formats are described in :mod:`cliport.deploy.importer` and :mod:`cliport.data.ravens`, and in the
README ("Importing real demonstrations", "Coming from the reference CLIPort").
"""

from __future__ import annotations

import argparse
import json
import sys

from cliport.cli.common import OneLineParser, run_cli


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="cliport-import",
        description="Convert a folder of real demonstrations (DIR/episode-XXX/ with cameras.json and steps.json: "
        "per step rgb and depth files, one per camera, pick and place poses in the robot base frame and the "
        "instruction), or a dataset split written by the reference CLIPort's or Ravens' demos.py "
        "({task}-{mode}/{action,color,depth,info,reward}/{index:06d}-{seed}.pkl), into "
        "DATA_DIR/<task>-<mode>/<seed>.npz, fused as the simulator fuses, so cliport-train uses them like "
        "simulated demonstrations. Re-running resumes. Prints a JSON summary.",
    )
    parser.add_argument(
        "--from", dest="src", required=True, metavar="DIR", help="folder of episode-XXX folders, or a Ravens split"
    )
    parser.add_argument(
        "--format",
        choices=["auto", "real", "ravens"],
        default="auto",
        help="real: episode-XXX folders; ravens: the reference's demos.py layout; auto: ravens when DIR has "
        "action/ and color/ folders",
    )
    parser.add_argument(
        "--task", help="a registered task name (cliport-tasks lists them; ravens: default from DIR's name)"
    )
    parser.add_argument("--data-dir", required=True, help="dataset root, as for cliport-demos and cliport-train")
    parser.add_argument("--mode", choices=["train", "val", "test"], help="default: train (ravens: from DIR's name)")
    parser.add_argument(
        "--bounds",
        nargs=6,
        type=float,
        metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
        help="workspace in the base frame, metres (default 0.25 0.75 -0.5 0.5 0 0.28; may move, not resize)",
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    from cliport.data.ravens import import_ravens, is_ravens_dataset
    from cliport.deploy.importer import import_demos
    from cliport.deploy.predictor import check_bounds
    from cliport.errors import ConfigError

    if args.format == "ravens" or (args.format == "auto" and is_ravens_dataset(args.src)):
        if args.bounds is not None:
            raise ConfigError("--bounds is for real demonstrations; a Ravens dataset has the reference's workspace")
        print(json.dumps(import_ravens(args.src, args.data_dir, args.task, args.mode)))
        return
    if args.task is None:
        raise ConfigError("--task is required for real demonstrations (episode-XXX folders)")
    bounds = check_bounds(args.bounds)
    summary = import_demos(args.src, args.task, args.data_dir, args.mode or "train", bounds)
    for note in summary.pop("notes"):
        print(f"note: {note}", file=sys.stderr)
    print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
