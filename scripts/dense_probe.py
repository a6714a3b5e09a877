"""Dense retrieval on the language lesson's scenes (cliport/pretrain/dense_retrieval.py): how often the similarity map
of an encoder's dense text-aligned embeddings with "a red block" is highest on the red block, of the scene's three,
seen and unseen colours apart, at each image scale asked for. Prints one JSON object (and writes it to --out).

    python scripts/dense_probe.py --clip-weights out/pretrain/open_clip_model.safetensors --scales 0.5 1 2
    python scripts/dense_probe.py --clip-weights random --semantic-encoder cliport-RN-tiny
    python scripts/dense_probe.py --clip-weights out/pretrain/open_clip_model.safetensors --scales 1 --bank
"""

from __future__ import annotations

import json

from cliport.cli.common import OneLineParser, run_cli
from cliport.errors import ConfigError
from cliport.utils.files import write_text
from cliport.utils.machine import measurement_environment

TASK = "put-one-block-in-bowl-unseen-colors"


def main() -> None:
    parser = OneLineParser(prog="dense_probe.py", description=__doc__.splitlines()[0])
    parser.add_argument("--clip-weights", required=True, help="a weights file (cliport-pretrain's), a tag, or random")
    parser.add_argument("--semantic-encoder", help="the open_clip model (default: the one a weights file names)")
    parser.add_argument("--task", default=TASK, help="a put-one-block-in-bowl-* task")
    parser.add_argument("--scenes", type=int, default=50, help="test scenes (the first of the test split)")
    parser.add_argument("--scales", nargs="+", type=float, default=[0.5, 1.0, 2.0], help="image scales to read at")
    parser.add_argument(
        "--bank",
        action="store_true",
        help="also read each map as its caption's probability against the seen colours' block and bowl captions "
        "(as agents with similarity_bank read them)",
    )
    parser.add_argument("--out", help="also write the JSON here")
    args = parser.parse_args()
    if args.scenes < 1 or any(s <= 0 for s in args.scales):
        raise ConfigError(f"--scenes must be >= 1 and --scales > 0, got {args.scenes} and {args.scales}")
    from cliport.data.seeds import episode_seeds
    from cliport.models.encoders.clip_encoder import load_clip
    from cliport.pretrain.dense_retrieval import dense_retrieval
    from cliport.tasks.colors import split_colors

    model = args.semantic_encoder
    if model is None:
        if args.clip_weights in ("random", "openai"):
            raise ConfigError(f"--clip-weights {args.clip_weights} needs --semantic-encoder NAME")
        from cliport.models.encoders.clip_weights import MODEL_NAME_KEY
        from cliport.pretrain.checkpoint import read_open_clip_metadata

        model = read_open_clip_metadata(args.clip_weights).get(MODEL_NAME_KEY)
        if not model:
            raise ConfigError(f"{args.clip_weights} does not name its model: pass --semantic-encoder")
    encoder = load_clip(args.clip_weights, model)
    seeds = episode_seeds("test", args.scenes)
    report = {"task": args.task, "clip_weights": args.clip_weights, "semantic_encoder": model, "scales": {}}
    banks = {"cosine": ()} if not args.bank else {"cosine": (), "bank": split_colors("train", False)}
    for how, colors in banks.items():
        for scale in args.scales:
            result = dense_retrieval(encoder, args.task, seeds, scale=scale, bank_colors=colors)
            key = str(scale) if how == "cosine" else f"{scale} bank"
            report["scales"][key] = {k: result[k] for k in ("seen", "unseen", "scenes", "bank")}
            print(f"scale {scale}, {how}: seen {result['seen']['found']}/{result['seen']['n']}, unseen "
                  f"{result['unseen']['found']}/{result['unseen']['n']} found (chance 1 in 3)", flush=True)  # fmt: skip
    report["environment"] = measurement_environment()
    text = json.dumps(report, indent=2)
    if args.out:
        write_text(args.out, text + "\n")
    print(text)


if __name__ == "__main__":
    run_cli(main)
