"""The task registry: tasks and multi-task groups by name.

Add a task by adding a module to this package that defines a ``Task`` subclass decorated with
``@register("my-task")``; ``make("my-task", mode)`` then builds it. Multi-task groups are named
lists of tasks (``register_group``; ``resolve("multi-language-conditioned")`` gives their members).
"""

from __future__ import annotations

import difflib
import importlib
import os
import pkgutil
from collections.abc import Callable
from typing import TypeVar

from cliport.errors import UnknownNameError
from cliport.tasks.base import Task

_PACKAGE = __name__.rpartition(".")[0]
_REGISTRY: dict[str, type[Task]] = {}
_GROUPS: dict[str, list[str]] = {}
_discovered = False


_Task = TypeVar("_Task", bound=Task)


def register(name: str) -> Callable[[type[_Task]], type[_Task]]:
    """Class decorator: make a Task subclass available as ``make(name)``."""

    def wrap(cls: type[_Task]) -> type[_Task]:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"task name {name!r} is registered twice")
        _REGISTRY[name] = cls
        return cls

    return wrap


def register_splits(base: type[_Task], seen: str, unseen: str) -> tuple[type[_Task], type[_Task]]:
    """Register ``base``'s two splits: ``seen`` (``unseen = False``: the training colours or objects) and
    ``unseen`` (``unseen = True``: the held-out ones at test time). The classes are named after the tasks
    (``put-block-in-bowl-seen-colors`` -> ``PutBlockInBowlSeenColors``) in ``base``'s module; assign them
    to those names there so that they pickle."""
    made: list[type[_Task]] = []
    for name, held_out in ((seen, False), (unseen, True)):
        title = "".join(part.capitalize() for part in name.split("-"))
        cls = type(title, (base,), {"unseen": held_out, "__module__": base.__module__, "__qualname__": title})
        made.append(register(name)(cls))
    return made[0], made[1]


def register_group(name: str, members: list[str]) -> None:
    """Name a list of tasks (a multi-task group) usable wherever a task name is."""
    _GROUPS[name] = list(members)


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    for info in pkgutil.iter_modules([os.path.dirname(__file__)]):
        if info.name not in ("base", "registry") and not info.name.startswith("_"):
            importlib.import_module(f"{_PACKAGE}.{info.name}")
    _discovered = True


def names() -> list[str]:
    """All registered task names, sorted."""
    _discover()
    return sorted(_REGISTRY)


def place_yaw_informative(name: str) -> bool:
    """Whether any task of ``name`` (a task or a multi-task group) needs place rotations, i.e. its
    expert's place yaw carries information (see ``Task.place_yaw_informative``)."""
    return any(_REGISTRY[task].place_yaw_informative for task in resolve(name))


def with_instruction_variants() -> list[str]:
    """The tasks whose scenes admit other instructions, with an oracle for each (demos can record them all)."""
    return [name for name in names() if _REGISTRY[name].offers_instruction_variants]


def groups() -> dict[str, list[str]]:
    """All multi-task groups by name."""
    _discover()
    return {k: list(v) for k, v in _GROUPS.items()}


def resolve(name: str) -> list[str]:
    """The task names a task or group name stands for; a clear error for an unknown name."""
    _discover()
    if name in _REGISTRY:
        return [name]
    if name in _GROUPS:
        return list(_GROUPS[name])
    close = difflib.get_close_matches(name, list(_REGISTRY) + list(_GROUPS), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise UnknownNameError(f"unknown task {name!r}{hint}; `cliport-tasks` lists them")


def make(name: str, mode: str = "train") -> Task:
    """A fresh task instance by name; ``mode`` ('train', 'val', 'test') selects its split."""
    resolved = resolve(name)
    if name not in _REGISTRY:
        raise UnknownNameError(f"{name!r} is a multi-task group, not a single task: {', '.join(resolved)}")
    task = _REGISTRY[name](mode=mode)
    task.name = name
    return task


__all__ = [
    "groups",
    "make",
    "names",
    "place_yaw_informative",
    "register",
    "register_group",
    "resolve",
    "with_instruction_variants",
]
