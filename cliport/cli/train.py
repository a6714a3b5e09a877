"""cliport-train: train an agent on demonstrations, then validate its checkpoints by task success.

Every flag is a field of the train config (``cliport.train.config.TrainConfig``), of the agents' configs
or of the workcell config; defaults come from ``configs/train.toml``, ``configs/<agent>.toml`` and
``configs/env.toml``, and the run saves its resolved config as ``RUN/config.json``. An agent flag the chosen
agent does not have (``--clip-weights`` for transporter_only) is an error, as in ``TrainConfig.build``. Building
the parser (and ``--help``) imports no agent and no torch.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from cliport.cli.common import OneLineParser, parse_key_values, run_cli
from cliport.errors import ConfigError, RunDirError

if TYPE_CHECKING:
    from cliport.train.config import TrainConfig


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.agents.registry import agent_names, config_classes
    from cliport.env.config import EnvConfig
    from cliport.train.config import TrainConfig
    from cliport.utils.config import add_flags

    parser = OneLineParser(
        prog="cliport-train",
        description=f"Train an agent ({', '.join(agent_names())}); defaults come from configs/train.toml, "
        "configs/<agent>.toml and configs/env.toml. Checkpoints and metrics go to --run-dir.",
    )
    taken: set[str] = set()
    dests = add_flags(parser.add_argument_group("run"), [TrainConfig], taken=taken)
    dests += add_flags(parser.add_argument_group("agent"), config_classes(), "agent_config", taken=taken)
    dests += add_flags(parser.add_argument_group("workcell of the validation episodes"), [EnvConfig], "env",
                       skip=("raw_images",), taken=taken)  # fmt: skip
    parser.add_argument(
        "--agent-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set any agent config field, e.g. n_rotations=12 (repeatable)",
    )
    parser.add_argument("--resume", action="store_true", help="continue the run in --run-dir from its last save")
    parser.add_argument("--no-progress", action="store_true")
    return parser, dests


def config_from_args(args: argparse.Namespace, dests: list[str]) -> TrainConfig:
    """The resolved TrainConfig: defaults (or the resumed run's saved config) updated with the given flags."""
    from cliport.train.config import TrainConfig, load_run_config
    from cliport.utils.config import given_flags, merge

    given: dict[str, Any] = given_flags(args, dests)
    if args.resume and "run_dir" in given:
        given.setdefault("agent", load_run_config(given["run_dir"]).agent)
    options = parse_key_values(args.agent_option, "--agent-option")
    given = merge(given, {"agent_config": options}) if options else given
    if args.resume:
        if "run_dir" not in given:
            raise ConfigError("--resume needs --run-dir (the run to continue)")
        saved = load_run_config(given["run_dir"])
        if "agent" in given and given["agent"] != saved.agent:
            raise RunDirError(f"{given['run_dir']} is a run of agent {saved.agent!r}, not {given['agent']!r}")
        if "recipe" in given and given["recipe"] != saved.recipe:
            raise RunDirError(
                f"{given['run_dir']} trains with the {saved.recipe} recipe, not {given['recipe']}: "
                "a run keeps its recipe (start another --run-dir)"
            )
        return TrainConfig.build(given, base=saved.to_dict())
    if not given.get("task"):
        raise ConfigError("--task is required")
    from cliport.train.run_defaults import run_defaults

    defaults = run_defaults(
        given["task"],
        n_rotations=given.get("agent_config", {}).get("n_rotations"),
        renderer=given.get("env", {}).get("renderer"),
    )
    if defaults.note:
        print(defaults.note, file=sys.stderr)
    return TrainConfig.build(merge(given, defaults.overrides()))


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    config = config_from_args(args, dests)
    from cliport import tasks
    from cliport.evaluation.engine import resolve_workers
    from cliport.evaluation.validation import make_validator
    from cliport.train.trainer import train
    from cliport.utils.device import resolve_device

    tasks.resolve(config.task)
    validator = None
    if config.val_workers is not None and config.val_episodes == 0:
        raise ConfigError("--val-workers needs validation: --val-episodes is 0")
    if config.val_episodes > 0:
        workers = resolve_workers(config.val_workers, config.val_episodes, "--val-workers")
        validator = make_validator(
            config.val_mode,
            resolve_device(config.device),
            run_dir=config.resolved_run_dir(),
            task=config.task,
            n_episodes=config.val_episodes,
            camera_scale=config.env.camera_scale,
            progress=not args.no_progress,
            workers=workers,
            renderer=config.env.renderer,
        )
    summary = train(config, resume=args.resume, progress=not args.no_progress, validator=validator)
    if summary.pop("rank", 0) == 0:
        print(json.dumps(summary, indent=2))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
