"""Instruction following: on a test scene, name another block than the task's, and see which block is picked.

For each scene (a task seed), every block other than the one the task's instruction names is named in turn,
with the same bowl ("put the blue block in the green bowl" instead of "... red block ..."), and the agent acts
once on the unchanged first observation. A swap is followed when the pick lands on the named block: within
its 4 cm square footprint, in the block's own frame, plus :data:`MARGIN`. Needs a task that knows its blocks'
colours (``block_colors``, ``goal_block``, ``goal_bowl`` and ``instruction_for``: put-one-block-in-bowl-*).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from cliport.errors import ConfigError
from cliport.tasks.blocks_assets import BLOCK

MARGIN = 0.005  # m beyond the block's half-width: the suction cup's rim


def on_block(pick_xy: np.ndarray, block_xy: np.ndarray, block_yaw: float) -> bool:
    """Whether the point ``pick_xy`` (m) lies on a block centred at ``block_xy`` with yaw ``block_yaw``."""
    c, s = np.cos(block_yaw), np.sin(block_yaw)
    dx, dy = pick_xy[0] - block_xy[0], pick_xy[1] - block_xy[1]
    local = (c * dx + s * dy, -s * dx + c * dy)
    return max(abs(local[0]), abs(local[1])) <= BLOCK[0] / 2 + MARGIN


def lesson_task(task_name: str, mode: str, what: str) -> Any:
    """The task ``task_name``; a ConfigError unless it can name any of its blocks (put-one-block-in-bowl-*)."""
    from cliport import tasks

    task = tasks.make(task_name, mode)
    if not hasattr(task, "instruction_for"):
        raise ConfigError(
            f"{what} needs a task that names its blocks' colours (put-one-block-in-bowl-*), not {task_name}"
        )
    return task


def block_poses(task: Any) -> dict[str, tuple[np.ndarray, float]]:
    """Each block of a reset put-one-block-in-bowl-* scene: colour -> (centre xy (2,) m, yaw rad)."""
    from cliport.env.transforms import quat_to_yaw

    poses = {}
    for name, body in task.block_colors.items():
        xyz, quat = task._pose(body)
        poses[name] = (np.asarray(xyz[:2], dtype=np.float64), float(quat_to_yaw(quat)))
    return poses


def instruction_following(
    agent: Any,
    task_name: str,
    seeds: Iterable[int],
    camera_scale: float = 1.0,
    mode: str = "test",
    on_swap: Callable[[dict[str, Any], dict[str, Any], str], None] | None = None,
) -> dict[str, Any]:
    """Swap the named block on each scene of ``seeds``; ``{"rate", "n", "followed", "swaps"}``.

    ``swaps`` lists each swap: seed, instruction, named colour, the colour of the block picked (None: no
    block) and whether it was followed. ``on_swap(obs, act, instruction)`` sees every action.
    """
    from cliport.env.environment import EnvConfig, Environment

    task = lesson_task(task_name, mode, "instruction following")
    swaps = []
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        for seed in seeds:
            obs = env.reset(seed=seed)
            blocks = block_poses(task)
            for name in blocks:
                if name == task.goal_block:
                    continue
                instruction = task.instruction_for(name, task.goal_bowl)
                act = agent.act(obs, instruction)
                pick_xy = np.asarray(act["pose0"][0][:2])
                picked = next((other for other, (xy, yaw) in blocks.items() if on_block(pick_xy, xy, yaw)), None)
                swaps.append(
                    {"seed": int(seed), "instruction": instruction, "named": name, "picked": picked,
                     "followed": picked == name}
                )  # fmt: skip
                if on_swap is not None:
                    on_swap(obs, act, instruction)
    followed = sum(s["followed"] for s in swaps)
    return {"rate": followed / len(swaps) if swaps else 0.0, "n": len(swaps), "followed": followed, "swaps": swaps}


def scene_instruction(task_name: str, seed: int, camera_scale: float = 1.0, mode: str = "test") -> str | None:
    """The instruction of scene ``seed`` of ``task_name`` (its first goal's)."""
    return scene_instructions(task_name, [seed], camera_scale, mode)[seed]


def scene_instructions(
    task_name: str, seeds: list[int], camera_scale: float = 1.0, mode: str = "test"
) -> dict[int, str | None]:
    """The instruction of each scene of ``seeds`` (its first goal's), from one simulator."""
    from cliport import tasks
    from cliport.env.environment import EnvConfig, Environment

    task = tasks.make(task_name, mode)
    out: dict[int, str | None] = {}
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        for seed in seeds:
            env.reset(seed=seed)
            out[seed] = task.lang_goal
    return out


def two_instructions_figure(
    agent: Any, task_name: str, seed: int, path: str, camera_scale: float = 1.0, mode: str = "test"
) -> list[str]:
    """One scene, two instructions: the task's own, and one naming another block and the other bowl; the
    observation and pick/place heatmaps of each (:func:`action_panel`) stacked in one PNG at ``path``.
    Returns the two instructions."""
    from cliport.env.environment import EnvConfig, Environment
    from cliport.evaluation.visualize import action_panel, save_png

    task = lesson_task(task_name, mode, "the two-instruction figure")
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        obs = env.reset(seed=seed)
        own = task.lang_goal
        block = next(name for name in task.block_colors if name != task.goal_block)
        bowl = next(name for name in task.bowl_colors if name != task.goal_bowl)
        other = task.instruction_for(block, bowl)
    panels = [
        action_panel(obs, agent.act(obs, lang), lang, similarity=agent.similarity_heatmaps(obs, lang))
        for lang in (own, other)
    ]
    save_png(path, np.concatenate(panels, axis=0))
    return [own, other]
