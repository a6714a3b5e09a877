"""The tasks as Gymnasium environments: ``gymnasium.make("cliport/<task>-v0")`` (registered on ``import cliport``).

A thin wrapper over :class:`cliport.env.environment.Environment` (which the evaluation engine keeps using):
the Gymnasium reset/step signatures, spaces, ``render()`` and the scripted expert. No torch here.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cliport import tasks
from cliport.data.seeds import episode_seeds
from cliport.env import heightmap
from cliport.env.environment import EnvConfig, Environment, validate_action
from cliport.errors import ConfigError

SPLITS = ("train", "val", "test")
#: How far above the workspace box a place may go (a held object set on top of a stack), as
#: :func:`~cliport.env.environment.validate_action` allows.
PLACE_HEADROOM = 0.1
_DRAWN_SEEDS = 2**20  # seed=None draws one of this many seeds of the split
#: Depth images reach the far plane up to the float32 rounding of the depth formula (10.0007 m for 10 m).
_FAR_SLACK = 1.001


def _pose_space(bounds: np.ndarray) -> spaces.Tuple:
    low = bounds[:, 0].astype(np.float64)
    high = bounds[:, 1].astype(np.float64) + np.array([0.0, 0.0, PLACE_HEADROOM])
    position = spaces.Box(low, high, dtype=np.float64)
    rotation = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float64)  # quaternion xyzw, normalised on use
    return spaces.Tuple((position, rotation))


def _as_action(action: dict[str, Any]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{"pose0": (xyz, quat), "pose1": ...}`` with float64 arrays, as the action space holds them."""
    return {
        name: (np.asarray(action[name][0], dtype=np.float64), np.asarray(action[name][1], dtype=np.float64))
        for name in ("pose0", "pose1")
    }


class CliportEnv(gym.Env):
    """One task of the workcell as a Gymnasium environment.

    Observation (a Dict): ``color`` (320, 160, 3) uint8 and ``height`` (320, 160) float32 (metres above the
    table), the top-down maps the agents see; with ``raw_images=True`` also ``cameras``, a tuple of the
    three cameras' ``color`` (H, W, 3) uint8 and ``depth`` (H, W) float32 (metres).

    Action (a Dict): ``pose0`` (pick, or push start) and ``pose1`` (place, or push end), each a tuple
    (position xyz in metres, world frame; quaternion xyzw). Extra keys are ignored, so an agent's
    ``act()`` result can be passed as it is; a malformed action raises
    :class:`~cliport.env.environment.ActionError` naming the field, before the simulator moves.

    ``reset(seed=s)`` builds cliport's episode ``s`` of the split (the test episodes of ``cliport-eval``
    are 10001, 10003, ...); ``reset()`` draws a seed of the split from the environment's generator.
    ``terminated`` when the task is done, ``truncated`` at the task's step limit. ``info`` holds
    ``lang_goal`` (the instruction in force), ``seed``, ``steps``, ``total_reward`` and, after a step,
    ``is_success`` (total reward > 0.99), ``grasped`` and ``reached``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        task: str,
        split: str = "train",
        camera_scale: float | None = None,
        renderer: str | None = None,
        raw_images: bool = False,
        render_mode: str | None = None,
    ) -> None:
        """``task``: a task name (``cliport-tasks``); ``split``: train, val or test (tasks with seen and
        unseen colours draw them by split); ``camera_scale``, ``renderer``: the workcell settings
        (default ``configs/env.toml``); ``raw_images``: add the three camera images to observations;
        ``render_mode``: None or "rgb_array" (the front camera)."""
        if split not in SPLITS:
            raise ConfigError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.task_name = task
        self.split = split
        self.render_mode = render_mode
        self.task = tasks.make(task, split)
        config = EnvConfig.defaults(camera_scale=camera_scale, renderer=renderer, raw_images=raw_images)
        self.sim = Environment(config, task=self.task)
        self.raw_images = raw_images
        self.observation_space = self._observation_space()
        pose = _pose_space(self.sim.bounds)
        self.action_space = spaces.Dict({"pose0": pose, "pose1": pose})
        self._obs: dict[str, Any] | None = None
        self._total_reward = 0.0

    def _observation_space(self) -> spaces.Dict:
        rows, cols = heightmap.heightmap_shape(self.sim.bounds, self.sim.pixel_size)
        top = float(self.sim.bounds[2, 1] - self.sim.bounds[2, 0])
        fields: dict[str, spaces.Space] = {
            "color": spaces.Box(0, 255, (rows, cols, 3), dtype=np.uint8),
            "height": spaces.Box(0.0, top, (rows, cols), dtype=np.float32),
        }
        if self.raw_images:
            fields["cameras"] = spaces.Tuple(
                spaces.Dict(
                    {
                        "color": spaces.Box(0, 255, (*cam.image_size, 3), dtype=np.uint8),
                        "depth": spaces.Box(0.0, cam.zrange[1] * _FAR_SLACK, tuple(cam.image_size), dtype=np.float32),
                    }
                )
                for cam in self.sim.camera_configs
            )
        return spaces.Dict(fields)

    def _observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {"color": obs["color"], "height": obs["height"]}
        if self.raw_images:
            out["cameras"] = tuple({"color": c["color"], "depth": c["depth"]} for c in obs["cameras"])
        return out

    def _info(self) -> dict[str, Any]:
        return {
            "lang_goal": self.sim.lang_goal,
            "seed": self.sim.seed,
            "steps": self.sim.steps,
            "total_reward": self._total_reward,
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Build episode ``seed`` (None: a seed of the split drawn from ``self.np_random``); (obs, info)."""
        super().reset(seed=seed)
        if options:
            raise ConfigError(f"reset() takes no options, got {sorted(options)}")
        if seed is None:
            seed = episode_seeds(self.split, 1, int(self.np_random.integers(_DRAWN_SEEDS)))[0]
        self._obs = self.sim.reset(int(seed))
        self._total_reward = 0.0
        return self._observation(self._obs), self._info()

    def step(self, action: dict[str, Any]) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """Execute one pick-and-place (or push); (obs, reward, terminated, truncated, info)."""
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        validate_action(action, self.sim.bounds)  # ActionError naming the field, before anything moves
        obs, reward, _, info = self.sim.step({"pose0": action["pose0"], "pose1": action["pose1"]})
        self._obs = obs
        self._total_reward += reward
        terminated = bool(self.task.done())
        truncated = not terminated and self.sim.steps >= self.task.max_steps
        info = {**info, **self._info(), "is_success": self._total_reward > 0.99}
        return self._observation(obs), float(reward), terminated, truncated, info

    def oracle_action(self) -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
        """The scripted expert's next action for the current state (as the action space holds it), or None
        when it finds none. It draws from the episode's generator, as demonstrations do."""
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before oracle_action()")
        action = self.task.oracle_act(self._obs)
        return None if action is None else _as_action(action)

    def render(self) -> np.ndarray | None:
        """The front camera's colour image (H, W, 3) uint8 at the workcell's camera scale ("rgb_array")."""
        if self.render_mode is None:
            gym.logger.warn("render() needs a render_mode: make the environment with render_mode='rgb_array'")
            return None
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        return self.sim.render_camera(self.sim.camera_configs[0])["color"]

    def close(self) -> None:
        sim = getattr(self, "sim", None)
        if sim is not None:
            sim.close()
            self.sim = None  # type: ignore[assignment]  # closed: no simulator until the next reset


__all__ = ["CliportEnv", "SPLITS"]
