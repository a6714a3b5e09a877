"""cliport-push: share a trained run on the Hugging Face Hub (or write the folder that would be pushed)."""

from __future__ import annotations

import argparse
import sys
import tempfile

from cliport.cli.common import OneLineParser, run_cli


def _parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="cliport-push",
        description="Upload a training run to a Hugging Face Hub model repo: config.json, model.safetensors (the "
        "pushed checkpoint's trained weights as safetensors, loadable without pickle; the val-selected one when "
        "pushed, else the newest), val.json, the chosen checkpoint(s) under checkpoints/ (trained weights only, no "
        "optimiser state, never frozen pretrained weights), the evaluation JSONs under eval/ and a generated "
        "README.md model card. The repo is a run folder: cliport-eval --run-dir hf://org/name reads it back, "
        "PickPlaceAgent.from_pretrained('hf://org/name') loads its model.safetensors.",
    )
    parser.add_argument("--run-dir", required=True, help="a cliport-train run folder")
    parser.add_argument("--repo", required=True, help="the Hub model repo, org/name")
    parser.add_argument(
        "--checkpoint", default="best", help="best (by validation), last, a saved step, or all (every saved one)"
    )
    parser.add_argument("--local-dir", help="only write the folder here (empty or new), upload nothing")
    parser.add_argument("--private", action="store_true", help="create the repo as private")
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    from cliport.deploy.hub import build_hub_folder, parse_hub_ref, summary, upload

    repo_id, revision = parse_hub_ref(args.repo)
    if revision is not None:
        from cliport.errors import ConfigError

        raise ConfigError(f"--repo takes org/name without a revision, got {args.repo!r}")
    if args.local_dir is not None:
        build_hub_folder(args.run_dir, args.local_dir, repo_id, args.checkpoint)
        print(summary(args.local_dir))
        return
    with tempfile.TemporaryDirectory(prefix="cliport-push-") as folder:
        build_hub_folder(args.run_dir, folder, repo_id, args.checkpoint)
        url = upload(folder, repo_id, private=args.private)
    print(f"pushed {args.run_dir} to https://huggingface.co/{repo_id} ({url})", file=sys.stderr)
    print(f"hf://{repo_id}")


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
