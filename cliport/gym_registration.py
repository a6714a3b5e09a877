"""Registers every task as the Gymnasium environment ``cliport/<task>-v0`` (run on ``import cliport``).

Cheap by design: it imports gymnasium only, and names the environment class by its string entry point, so
neither the simulator (pybullet) nor torch is imported until ``gymnasium.make`` builds one. The task names
are listed here for that reason; ``tests/test_gym_env.py`` checks the list against the task registry.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

NAMESPACE = "cliport"
ENTRY_POINT = "cliport.gym_env:CliportEnv"
#: Every registered task (``cliport.tasks.names()``); a new task must be added here too.
TASK_NAMES = (
    "align-box-corner",
    "align-rope",
    "assembling-kits",
    "assembling-kits-seq-seen-colors",
    "assembling-kits-seq-unseen-colors",
    "block-insertion",
    "manipulating-rope",
    "packing-boxes",
    "packing-boxes-pairs-seen-colors",
    "packing-boxes-pairs-unseen-colors",
    "packing-seen-objects-group",
    "packing-seen-objects-seq",
    "packing-shapes",
    "packing-unseen-objects-group",
    "packing-unseen-objects-seq",
    "palletizing-boxes",
    "place-red-in-green",
    "put-block-in-bowl-seen-colors",
    "put-block-in-bowl-unseen-colors",
    "put-one-block-in-bowl-seen-colors",
    "put-one-block-in-bowl-unseen-colors",
    "separating-piles-seen-colors",
    "separating-piles-unseen-colors",
    "stack-block-pyramid",
    "stack-block-pyramid-seq-seen-colors",
    "stack-block-pyramid-seq-unseen-colors",
    "sweeping-piles",
    "towers-of-hanoi",
    "towers-of-hanoi-seq-seen-colors",
    "towers-of-hanoi-seq-unseen-colors",
)


def env_id(task: str) -> str:
    """The Gymnasium id of a task: ``cliport/<task>-v0``."""
    return f"{NAMESPACE}/{task}-v0"


def register_envs() -> None:
    """Register ``cliport/<task>-v0`` for every task (each once, so a second call changes nothing)."""
    for task in TASK_NAMES:
        if env_id(task) not in registry:
            # The step limit is the task's own (truncated inside the environment), so no TimeLimit wrapper.
            register(id=env_id(task), entry_point=ENTRY_POINT, kwargs={"task": task})


__all__ = ["ENTRY_POINT", "NAMESPACE", "TASK_NAMES", "env_id", "register_envs"]
