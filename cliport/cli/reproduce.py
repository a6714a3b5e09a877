"""cliport-reproduce: train agents over demo counts, evaluate every checkpoint, compare with the papers.

The flags are the fields of ``cliport.study.StudyConfig`` (defaults in configs/study.toml) and the
agents' settings (``--width``, ``--clip-weights``, ...), which go to every run whose agent has them.
"""

from __future__ import annotations

import argparse
import json

from cliport.cli.common import OneLineParser, parse_key_values, run_cli
from cliport.errors import ConfigError


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.agents import agent_names, config_classes
    from cliport.study import StudyConfig
    from cliport.utils.config import add_flags

    parser = OneLineParser(
        prog="cliport-reproduce",
        description=f"{__doc__.split(':', 1)[1].strip().splitlines()[0]} Agents: {', '.join(agent_names())}.",
    )
    taken: set[str] = set()
    dests = add_flags(parser.add_argument_group("study"), [StudyConfig], taken=taken)
    dests += add_flags(parser.add_argument_group("agent settings"), config_classes(), "agent_config", taken=taken)
    parser.add_argument("--agent-option", action="append", default=[], metavar="KEY=VALUE",
                        help="set any agent config field, e.g. n_rotations=12 (repeatable)")  # fmt: skip
    parser.add_argument("--no-progress", action="store_true")
    return parser, dests


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    from cliport import tasks
    from cliport.agents import agent_class, agent_names
    from cliport.study import StudyConfig, run_study
    from cliport.utils.config import given_flags, load, merge

    given = given_flags(args, dests)
    options = parse_key_values(args.agent_option, "--agent-option")
    if options:
        given = merge(given, {"agent_config": options})
    if not given.get("task"):
        raise ConfigError("--task is required")
    config = load(StudyConfig, "study", given)
    tasks.resolve(config.task)
    config.agents = config.agents or agent_names()
    for name in config.agents:
        agent_class(name)
    if min(config.n_demos) < 1 or config.n_steps < 1:
        raise ConfigError("--n-demos and --n-steps must be positive")
    config.n_demos = sorted(set(config.n_demos))
    config.out = config.out or f"studies/{config.task}"
    results = run_study(config, progress=not args.no_progress)
    print(json.dumps({"out": config.out, "runs": len(results["runs"])}))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
