"""cliport-tasks: list the registered tasks and multi-task groups."""

from __future__ import annotations

from cliport.cli.common import OneLineParser, run_cli


def main(argv: list[str] | None = None) -> None:
    OneLineParser(prog="cliport-tasks", description=__doc__.split(":", 1)[1].strip()).parse_args(argv)
    from cliport import tasks

    for name in tasks.names():
        task = tasks.make(name)
        print(f"{name:45s} max_steps={task.max_steps:<3d} {task.end_effector}")
    for name, members in tasks.groups().items():
        print(f"{name:45s} group of {len(members)}: {', '.join(members)}")


def entry() -> None:
    run_cli(main)


if __name__ == "__main__":
    entry()
