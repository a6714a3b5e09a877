"""cliport-import: convert demonstrations into demonstration files: real ones (RGB-D views and pick/place
poses, :mod:`cliport.deploy.importer`) or datasets of the reference CLIPort and Ravens (the layout their
demos.py writes, :mod:`cliport.data.ravens_import`).

The formats are described in those modules and docs/your-scene.md ("Importing real demonstrations",
"Importing reference datasets").
"""

from __future__ import annotations

import argparse
import json
import sys

from cliport.cli.common import OneLineParser, run_cli


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="cliport-import",
        description="Convert demonstrations into DATA_DIR/<task>-<mode>/<seed>.npz, fused as the simulator fuses, "
        "so cliport-train uses them like simulated demonstrations: a folder of real demonstrations (DIR/episode-XXX/ "
        "with cameras.json and steps.json: per step rgb and depth files, one per camera, pick and place poses in the "
        "robot base frame and the instruction), or a dataset of the reference CLIPort or Ravens (DIR = <task>-<mode>/ "
        "with action/ color/ depth/ info/ reward/ holding one {index:06d}-{seed}.pkl per episode, as their demos.py "
        "writes; pickles are loaded safely: numpy arrays and built-in containers only). Re-running resumes. Prints a "
        "JSON summary.",
    )
    parser.add_argument(
        "--from",
        dest="src",
        required=True,
        metavar="DIR",
        help="folder of episode-XXX folders, or a <task>-<mode> folder",
    )
    parser.add_argument(
        "--format",
        default="auto",
        choices=["auto", "steps", "ravens"],
        help="steps: episode-XXX folders with steps.json; ravens: the reference's demos.py layout; auto (default): "
        "ravens when DIR has an action/ folder",
    )
    parser.add_argument("--task", required=True, help="a registered task name (cliport-tasks lists them)")
    parser.add_argument("--data-dir", required=True, help="dataset root, as for cliport-demos and cliport-train")
    parser.add_argument("--mode", default="train", choices=["train", "val", "test"])
    parser.add_argument(
        "--bounds",
        nargs=6,
        type=float,
        metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
        help="workspace in the base frame, metres (default 0.25 0.75 -0.5 0.5 0 0.28; may move, not resize); "
        "not for --format ravens, whose poses are in the simulator's frame",
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    from cliport.data.ravens_import import import_ravens, is_ravens_folder
    from cliport.deploy.importer import import_demos
    from cliport.deploy.predictor import check_bounds
    from cliport.errors import DemoImportError

    fmt = args.format
    if fmt == "auto":
        fmt = "ravens" if is_ravens_folder(args.src) else "steps"
    if fmt == "ravens":
        if args.bounds is not None:
            raise DemoImportError("--bounds does not apply to --format ravens: its poses are in the simulator's frame")
        summary = import_ravens(args.src, args.task, args.data_dir, args.mode)
    else:
        summary = import_demos(args.src, args.task, args.data_dir, args.mode, check_bounds(args.bounds))
    for note in summary.pop("notes"):
        print(f"note: {note}", file=sys.stderr)
    print(json.dumps(summary))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
