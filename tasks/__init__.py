"""Task definitions, one module per task family, found through a registry by name (:mod:`cliport.tasks.registry`).

The names below are re-exported from the modules that hold them: the ``Task`` base (``base``) and the registry
(``registry``). Nothing in this package imports this ``__init__``.
"""

from cliport.tasks.base import GoalStep, Task
from cliport.tasks.registry import (
    groups,
    make,
    names,
    place_yaw_informative,
    register,
    register_group,
    resolve,
    with_instruction_variants,
)

__all__ = [
    "GoalStep",
    "Task",
    "groups",
    "make",
    "names",
    "place_yaw_informative",
    "register",
    "register_group",
    "resolve",
    "with_instruction_variants",
]
