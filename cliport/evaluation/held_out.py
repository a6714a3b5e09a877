"""Held-out checks of a language-conditioned agent while it trains: every instruction of a few validation scenes
(the task's val split, never its test scenes), each scored from one action without running the episode.

A put-one-block-in-bowl-* scene has 3 blocks x 2 bowls, so 6 instructions. For each, the agent acts once on the
scene's first observation (:meth:`~cliport.agents.base.PickPlaceAgent.act_batch`, the six at once). The **pick** is
right when it lands on the named block (its footprint plus the suction cup's rim, as
:mod:`~cliport.evaluation.instruction_following` counts a swap followed). The **place** is right when the block
the pick landed on, carried by the same offset and turned by the place's yaw, would come down within the task's
bowl tolerance of the named bowl's centre (the test of a block in a bowl, without the physics): the bowl word.
A sample is **solved** when both are right. Scoring a scene costs two batched forward passes, so the lesson can
check its agent every few hundred steps and keep the best one (:class:`HeldOutCheck`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cliport.data.seeds import episode_seeds
from cliport.evaluation.instruction_following import block_poses, lesson_task, on_block


@dataclass
class HeldOutScene:
    """One scene's first observation and where its objects are: ``blocks`` colour -> (centre xy (2,) m, yaw rad),
    ``bowls`` colour -> centre xy (2,) m."""

    seed: int
    color: np.ndarray  # (H, W, 3) uint8
    height: np.ndarray  # (H, W) float32, metres
    blocks: dict[str, tuple[np.ndarray, float]]
    bowls: dict[str, np.ndarray]
    tolerance: float  # m: a block centre this near a bowl's centre is in it
    #: Every (instruction, block, bowl) of the scene: blocks in scene order, then bowls.
    instructions: list[tuple[str, str, str]]


def record_scenes(task_name: str, n_scenes: int, camera_scale: float = 1.0, mode: str = "val") -> list[HeldOutScene]:
    """The first ``n_scenes`` scenes of ``mode`` (val: never the test scenes) of a put-one-block-in-bowl-* task:
    each reset once, its observation and its objects' poses kept (about half a second a scene)."""
    from cliport.env.environment import EnvConfig, Environment
    from cliport.tasks.blocks_assets import BOWL_TOLERANCE

    task = lesson_task(task_name, mode, "held-out checks")
    scenes = []
    with Environment(EnvConfig.defaults(camera_scale=camera_scale), task=task) as env:
        for seed in episode_seeds(mode, n_scenes):
            obs = env.reset(seed=seed)
            blocks = block_poses(task)
            bowls = {name: np.asarray(pose[0][:2], dtype=np.float64) for name, pose in task.bowl_colors.items()}
            color, height = np.asarray(obs["color"]), np.asarray(obs["height"], dtype=np.float32)
            named = [(task.instruction_for(block, bowl), block, bowl) for block in blocks for bowl in bowls]
            scenes.append(HeldOutScene(int(seed), color, height, blocks, bowls, BOWL_TOLERANCE, named))
    return scenes


def _landing(act: dict[str, Any], block_xy: np.ndarray) -> np.ndarray:
    """Where a block picked at ``act``'s pick comes down: the place point plus the block's offset from the pick,
    turned by the place's yaw."""
    pick = np.asarray(act["pose0"][0][:2])
    place = np.asarray(act["pose1"][0][:2])
    c, s = np.cos(act["place_rot"]), np.sin(act["place_rot"])
    dx, dy = block_xy - pick
    return place + np.array([c * dx - s * dy, s * dx + c * dy])


def score_scenes(agent: Any, scenes: list[HeldOutScene]) -> dict[str, Any]:
    """Every instruction of every scene, acted on once: ``{"n", "picks", "places", "solved"}`` (counts) and the
    fraction ``score`` = solved / n. Leaves the agent in eval mode."""
    picks = places = solved = n = 0
    for scene in scenes:
        named = scene.instructions
        obs = {"color": scene.color, "height": scene.height}
        acts = agent.act_batch([obs] * len(named), [text for text, _, _ in named])
        for (_, block, bowl), act in zip(named, acts, strict=True):
            pick_xy = np.asarray(act["pose0"][0][:2])
            picked = next((name for name, (xy, yaw) in scene.blocks.items() if on_block(pick_xy, xy, yaw)), None)
            pick_right = picked == block
            place_right = picked is not None and bool(
                np.linalg.norm(_landing(act, scene.blocks[picked][0]) - scene.bowls[bowl]) <= scene.tolerance
            )
            n += 1
            picks += pick_right
            places += place_right
            solved += pick_right and place_right
    return {"n": n, "picks": picks, "places": places, "solved": solved, "score": solved / n if n else 0.0}


class HeldOutCheck:
    """The lesson's check while training (the trainer's ``AgentCheck``): every ``every`` steps from ``start`` on, and
    at the last step, :func:`score_scenes` on ``scenes``; the trainer keeps the checkpoint of the best score."""

    def __init__(self, scenes: list[HeldOutScene], every: int, start: int = 0) -> None:
        if every < 1:
            raise ValueError(f"held-out checks need every >= 1 step, got {every}")
        self.scenes = scenes
        self.every = every
        self.start = start

    def due(self, step: int) -> bool:
        """Whether ``step`` is a scheduled check (the trainer also checks its last step)."""
        return step >= self.start and step % self.every == 0

    def check(self, step: int, agent: Any) -> dict[str, Any]:
        """The agent as it is after ``step`` steps, scored; ``score`` is what the best checkpoint maximises."""
        return score_scenes(agent, self.scenes)

    def describe(self) -> dict[str, Any]:
        """What results record about the check: scenes (their val seeds), samples, schedule."""
        return {
            "scenes": [scene.seed for scene in self.scenes],
            "samples": sum(len(scene.instructions) for scene in self.scenes),
            "every": self.every,
            "start": self.start,
        }
