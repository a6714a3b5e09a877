"""cliport-reproduce: train agents over tasks and demo counts, evaluate every checkpoint, compare with the papers.

The flags are the fields of ``cliport.study.StudyConfig`` (defaults in configs/study.toml) and the
agents' settings (``--width``, ``--clip-weights``, ...), which go to every run whose agent has them.
``--cluster local|auto|HOST:PORT`` runs the cells as Ray tasks (docs/cluster.md); ``--status OUT`` tells
how far the study in OUT has got.
"""

from __future__ import annotations

import argparse
import json
import sys

from cliport.cli.common import OneLineParser, parse_key_values, run_cli
from cliport.errors import ConfigError


def _parser() -> tuple[argparse.ArgumentParser, list[str]]:
    from cliport.agents.registry import agent_names, config_classes
    from cliport.study.config import StudyConfig
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
    parser.add_argument(
        "--train-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set another cliport-train setting of every run, e.g. num_workers=0 (repeatable)",
    )
    parser.add_argument(
        "--wait", action="store_true", help="if another driver runs the study in --out, wait for it instead of refusing"
    )
    parser.add_argument(
        "--status",
        metavar="OUT",
        help="print each cell of the study in OUT done / running / waiting, and the time left",
    )
    parser.add_argument("--no-progress", action="store_true")
    return parser, dests


def main(argv: list[str] | None = None) -> None:
    parser, dests = _parser()
    args = parser.parse_args(argv)
    if args.status:
        from cliport.study.status import status_report

        print(status_report(args.status))
        return
    from cliport import tasks
    from cliport.agents import agent_class, agent_names
    from cliport.study import StudyConfig, expand_tasks, run_study
    from cliport.utils.config import given_flags, load, merge

    given = given_flags(args, dests)
    for items, flag, key in (
        (args.agent_option, "--agent-option", "agent_config"),
        (args.train_option, "--train-option", "train_options"),
    ):
        options = parse_key_values(items, flag)
        if options:
            given = merge(given, {key: options})
    if given.get("task") and given.get("tasks"):
        raise ConfigError("give --task or --tasks, not both")
    if not given.get("task") and not given.get("tasks"):
        raise ConfigError("--task (or --tasks) is required")
    config = load(StudyConfig, "study", given)
    if config.tasks:
        names = config.tasks
        config.tasks = expand_tasks(names)  # a group stands for its tasks, e.g. studies/transporter-paper
        default_out = f"studies/{names[0]}" if len(names) == 1 else ""
        if not (config.out or default_out):
            raise ConfigError("--out is required when several tasks are studied")
    else:
        tasks.resolve(config.task)
        default_out = f"studies/{config.task}"
    config.agents = config.agents or agent_names()
    for name in config.agents:
        agent_class(name)
    if min(config.n_demos) < 1 or config.n_steps < 1:
        raise ConfigError("--n-demos and --n-steps must be positive")
    positive = {
        "--threads": config.threads,
        "--demo-shards": config.demo_shards,
        "--demo-workers": config.demo_workers,
        "--cell-cpus": config.cell_cpus or 1,
    }
    for flag, value in positive.items():
        if value < 1:
            raise ConfigError(f"{flag} must be >= 1, got {value}")
    if config.retries < 0:
        raise ConfigError(f"--retries must be >= 0, got {config.retries}")
    config.n_demos = sorted(set(config.n_demos))
    config.out = config.out or default_out
    for task in config.study_tasks():  # the papers' place rotations, where the task's place yaw says nothing too
        note = config.cell_defaults(task).note
        if note:
            print(note, file=sys.stderr)
    results = run_study(config, progress=not args.no_progress, wait=args.wait)
    runs = sum(len(r["runs"]) for r in results["tasks"])
    print(json.dumps({"out": config.out, "tasks": len(results["tasks"]), "runs": runs}))


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
