"""Scores of an unseen-colours evaluation split by what its instructions name: the block colour unseen, the bowl
colour unseen, both, or neither (CLIPort's ``-unseen-colors`` test palette shares blue, red and green with the
seen one, so its mean score mixes seen and unseen words).

Reads evaluation results (``cliport-eval``'s JSON, or a study cell's ``eval/TASK-test-STEP.json``) and prints one
JSON object: per file, per group, episodes, mean score with its 95 % interval and episodes solved, then the same
for the files' episodes pooled. Results written before episodes kept their instruction are read with
``--rebuild``: each episode's scene is reset to read it (deterministic: the same seed gives the same scene).

    python scripts/score_by_named.py studies/s0/runs/*/eval/put-block-in-bowl-unseen-colors-test-2000.json
"""

from __future__ import annotations

import json
import os

from cliport.cli.common import OneLineParser, run_cli
from cliport.errors import ConfigError
from cliport.utils.files import read_json


def parse_args() -> object:
    parser = OneLineParser(prog="score_by_named.py", description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", help="evaluation result JSON files")
    parser.add_argument(
        "--rebuild", action="store_true", help="read instructions an older result lacks from its scenes"
    )
    parser.add_argument("--camera-scale", type=float, default=0.5, help="camera resolution of --rebuild's scenes")
    return parser.parse_args()


def main() -> None:
    from cliport.evaluation.instruction_following import scene_instructions
    from cliport.pretrain.transfer import score_by_named

    args = parse_args()
    files: dict[str, object] = {}
    episodes: list[dict[str, object]] = []
    for path in args.results:
        if not os.path.isfile(path):
            raise ConfigError(f"no evaluation result at {path}")
        result = read_json(path)
        if "episodes" not in result or "task" not in result:
            raise ConfigError(f"{path} is not an evaluation result (no episodes)")
        missing = [e["seed"] for e in result["episodes"] if "instruction" not in e]
        if missing and not args.rebuild:
            raise ConfigError(f"{path}: {len(missing)} episodes record no instruction; pass --rebuild")
        if missing:
            found = scene_instructions(result["task"], missing, args.camera_scale, result.get("mode", "test"))
            for episode in result["episodes"]:
                episode.setdefault("instruction", found.get(episode["seed"]))
        try:
            files[path] = score_by_named(result)
        except ValueError as e:
            raise ConfigError(f"{path}: {e}") from e
        episodes += result["episodes"]
    report = {"files": files, "pooled": score_by_named({"episodes": episodes})}
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    run_cli(main)
