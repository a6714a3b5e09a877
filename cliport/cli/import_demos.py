"""cliport-import: convert real demonstrations (RGB-D views and pick/place poses) into demonstration files.

The source format is described in :mod:`cliport.deploy.importer` and the README ("Importing real
demonstrations").
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
        "instruction) into DATA_DIR/<task>-<mode>/<seed>.npz, fused as the simulator fuses, so cliport-train "
        "uses them like simulated demonstrations. Re-running resumes. Prints a JSON summary.",
    )
    parser.add_argument("--from", dest="src", required=True, metavar="DIR", help="folder of episode-XXX folders")
    parser.add_argument("--task", required=True, help="a registered task name (cliport-tasks lists them)")
    parser.add_argument("--data-dir", required=True, help="dataset root, as for cliport-demos and cliport-train")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
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
    from cliport.deploy.importer import import_demos
    from cliport.deploy.predictor import check_bounds

    bounds = check_bounds(args.bounds)
    summary = import_demos(args.src, args.task, args.data_dir, args.mode, bounds)
    for note in summary.pop("notes"):
        print(f"note: {note}", file=sys.stderr)
    print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
