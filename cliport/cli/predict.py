"""cliport-predict: one pick-and-place action of a trained run from your own RGB-D camera images."""

from __future__ import annotations

import argparse
import json
import os
import sys

from cliport.cli.common import OneLineParser, add_weight_flags, run_cli, weight_overrides
from cliport.errors import ConfigError


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="cliport-predict",
        description="Fuse your cameras' colour and depth images into the top-down map exactly as the simulator "
        "does, run a trained agent with an instruction, print the pick and place poses (robot base frame) as "
        "JSON and save the heatmaps. cameras.json: one object per camera with image_size [rows, cols], "
        "intrinsics (3x3), position [x, y, z] and rotation [x, y, z, w] (camera-to-world, z forward, y down), "
        "optional depth_scale (metres per unit of integer depth) and zrange.",
    )
    parser.add_argument("--run-dir", required=True, help="a cliport-train run folder, or hf://org/name[@revision]")
    parser.add_argument("--checkpoint", default="best", help="best (by validation), last, or a saved step")
    parser.add_argument("--rgb", nargs="+", metavar="IMAGE", help="colour images, one per camera (8-bit PNG/JPEG)")
    parser.add_argument(
        "--depth", nargs="+", metavar="DEPTH", help="depth images, one per camera: .npy float metres or 16-bit PNG"
    )
    parser.add_argument("--cameras", metavar="JSON", help="cameras.json, one object per camera (same order)")
    parser.add_argument(
        "--heightmap",
        nargs=2,
        metavar=("COLOR_PNG", "HEIGHT_NPY"),
        help="an already fused top-down map (320 x 160) instead of --rgb/--depth/--cameras",
    )
    parser.add_argument("--lang", required=True, help='the instruction, e.g. "pack the red block in the brown box"')
    parser.add_argument(
        "--bounds",
        nargs=6,
        type=float,
        metavar=("X0", "X1", "Y0", "Y1", "Z0", "Z1"),
        help="workspace in the base frame, metres (default 0.25 0.75 -0.5 0.5 0 0.28; may move, not resize)",
    )
    parser.add_argument("--device", default="auto", help="auto (CUDA when available), cpu, cuda, cuda:1, ...")
    add_weight_flags(parser)
    parser.add_argument("--out", required=True, help="folder for the heatmap picture, the fused map and the JSON")
    return parser


def _read_heightmap(color_path: str, height_path: str) -> tuple:
    import numpy as np

    from cliport.deploy.scene import SceneError, read_color

    color = read_color(color_path)
    if not height_path.lower().endswith(".npy") or not os.path.isfile(height_path):
        raise SceneError(f"height map {height_path} must be an existing .npy of float metres")
    try:
        height = np.load(height_path, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise SceneError(f"{height_path} is not a readable .npy array: {e}") from None
    return color, height


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    if not args.lang.strip():
        raise ConfigError("--lang must be a non-empty instruction")
    scene = [args.rgb, args.depth, args.cameras]
    if args.heightmap is not None and any(x is not None for x in scene):
        raise ConfigError("give either --heightmap or --rgb/--depth/--cameras, not both")
    if args.heightmap is None and any(x is None for x in scene):
        raise ConfigError("give --rgb, --depth and --cameras (one image of each per camera), or --heightmap")
    from cliport.deploy import Predictor, check_bounds, fuse_views, load_cameras, read_color, read_depth
    from cliport.deploy.scene import SceneError
    from cliport.evaluation.free_form import instruction_slug
    from cliport.evaluation.visualize import save_png
    from cliport.utils.files import write_json

    bounds = check_bounds(args.bounds)
    notes: list[str] = []
    if args.heightmap is None:
        cameras = load_cameras(args.cameras)
        if not len(args.rgb) == len(args.depth) == len(cameras):
            raise SceneError(
                f"{len(args.rgb)} --rgb image(s), {len(args.depth)} --depth image(s) and {len(cameras)} camera(s) "
                f"in {args.cameras}: give one colour and one depth image per camera, in the same order"
            )
        images = [
            (read_color(c), read_depth(d, cam, i))
            for i, (c, d, cam) in enumerate(zip(args.rgb, args.depth, cameras, strict=True))
        ]
        names = list(zip(args.rgb, args.depth, strict=True))
        obs, notes = fuse_views(images, cameras, bounds, names)
    else:
        color, height = _read_heightmap(*args.heightmap)
        obs = {"color": color, "height": height}
    predictor = Predictor(args.run_dir, args.checkpoint, args.device, bounds, weight_overrides(args))
    prediction = predictor.predict_heightmap(obs["color"], obs["height"], args.lang, notes)
    for note in prediction.notes:
        print(f"note: {note}", file=sys.stderr)
    stem = f"predict-{instruction_slug(args.lang)}"
    os.makedirs(args.out, exist_ok=True)
    result = prediction.to_json()
    result["heatmaps"] = os.path.join(args.out, f"{stem}-heatmaps.png")
    save_png(result["heatmaps"], prediction.panel())
    if args.heightmap is None:
        import numpy as np

        save_png(os.path.join(args.out, f"{stem}-color.png"), prediction.obs["color"])
        np.save(os.path.join(args.out, f"{stem}-height.npy"), prediction.obs["height"])
    write_json(os.path.join(args.out, f"{stem}.json"), result)
    print(json.dumps(result))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
