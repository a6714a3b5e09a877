"""cliport-pretrain: contrastive image-text pretraining of the semantic stream's encoders on rendered crops.

Renders crops of tabletop scenes once (resumable), trains the open_clip model ``--semantic-encoder`` with CLIP's
loss on them, writes its weights in open_clip's format (``OUT/open_clip_model.safetensors``, which ``--clip-weights
FILE --semantic-encoder NAME`` loads) and probes random against pretrained weights on held-out scenes. ``--probe
WEIGHTS`` only probes (``random``, a weights file, a pretrained tag) and prints the result as JSON. The settings
flags are the fields of ``cliport.pretrain.config.PretrainConfig`` (defaults in configs/pretrain.toml).
"""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import OneLineParser, run_cli


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.pretrain.config import PretrainConfig
    from cliport.utils.config import add_flags

    parser = OneLineParser(prog="cliport-pretrain", description=__doc__.split(":", 1)[1].strip().split("\n\n")[0])
    dests = add_flags(parser, [PretrainConfig])
    parser.add_argument(
        "--probe",
        metavar="WEIGHTS",
        help="only probe these weights of --semantic-encoder ('random', a weights file, a pretrained tag) on the "
        "held-out scenes of --cache-dir (rendered if missing) and print the result as JSON",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser, dests


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    from cliport.pretrain.cache import load_crops, load_scene_maps, render_cache
    from cliport.pretrain.config import load_config
    from cliport.pretrain.probe import check_weights_source, probe_weights
    from cliport.pretrain.trainer import check_device, pretrain, summary_lines
    from cliport.utils.config import given_flags

    config = load_config(given_flags(args, dests))
    if args.probe is not None:
        device = check_device(config.device)
        check_weights_source(args.probe, config.semantic_encoder)
        render_cache(
            config.cache_dir,
            {"probe": config.probe_scenes},
            config.crop_px,
            config.camera_scale,
            config.renderer,
            config.render_workers,
            progress=not args.no_progress,
        )
        crops = load_crops(config.cache_dir, "probe", config.probe_scenes)
        maps = load_scene_maps(config.cache_dir, "probe", config.probe_scenes)
        result = probe_weights(args.probe, config.semantic_encoder, crops, device, maps, config.dense_scale)
        print(json.dumps(result, indent=2))
        return
    record = pretrain(config, progress=not args.no_progress)
    print("\n".join(summary_lines(record)))
    print(
        f"use it: cliport-train --agent two_stream --semantic-encoder {record['semantic_encoder']} "
        f"--clip-weights {record['weights']} ..."
    )


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
