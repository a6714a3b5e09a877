"""The tasks as Gymnasium environments: registration on ``import cliport``, check_env, an oracle episode to
success through the wrapper, the spaces, render() and malformed actions."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cliport
from cliport import tasks
from cliport.env.environment import ActionError
from cliport.errors import ConfigError
from cliport.gym_registration import TASK_NAMES, env_id

TASK = "place-red-in-green"


@pytest.fixture(scope="module")
def env():
    e = gym.make(env_id(TASK), split="test", camera_scale=0.5)
    yield e
    e.close()


def test_every_task_is_registered() -> None:
    assert cliport.__name__ == "cliport"
    assert list(TASK_NAMES) == tasks.names(), "cliport/gym_registration.py TASK_NAMES must list every task"
    assert len(TASK_NAMES) == 30
    registered = {i for i in gym.registry if i.startswith("cliport/")}
    assert registered == {f"cliport/{name}-v0" for name in tasks.names()}


def test_importing_cliport_registers_without_the_simulator_or_torch() -> None:
    code = (
        "import sys, cliport, gymnasium; "
        "assert 'cliport/place-red-in-green-v0' in gymnasium.registry; "
        "print(sorted(m for m in ('pybullet', 'torch', 'cliport.env', 'cliport.gym_env') if m in sys.modules)); "
        "import cliport.gym_env; print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "False"]  # the wrapper itself does not need torch either


@pytest.mark.e2e  # ~20 s of resets and steps; the spaces and an oracle episode are checked below
def test_check_env_passes() -> None:
    env = gym.make(env_id(TASK), camera_scale=0.5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    # The only advice it gives: Box action spaces normalised to [-1, 1]; ours are metres in the workspace.
    others = [str(w.message) for w in caught if "symmetric and normalized" not in str(w.message)]
    assert not others, others


def test_oracle_episode_succeeds_through_the_wrapper(env) -> None:
    obs, info = env.reset(seed=10001)
    assert info["lang_goal"] == "put the red blocks in a green bowl" and info["seed"] == 10001
    assert obs in env.observation_space
    total, steps = 0.0, 0
    terminated = truncated = False
    while not (terminated or truncated):
        action = env.unwrapped.oracle_action()
        assert action is not None and action in env.action_space
        obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        steps += 1
        assert obs in env.observation_space and isinstance(reward, float)
    assert terminated and not truncated
    assert info["is_success"] and total == pytest.approx(1.0) and info["total_reward"] == pytest.approx(total)
    assert info["steps"] == steps < 10


def test_same_seed_same_scene_and_seedless_reset_draws_a_split_seed(env) -> None:
    first, _ = env.reset(seed=10003)
    again, _ = env.reset(seed=10003)
    np.testing.assert_array_equal(first["color"], again["color"])
    np.testing.assert_array_equal(first["height"], again["height"])
    _, info = env.reset()
    assert info["seed"] >= 10001 and info["seed"] % 2 == 1  # a test seed


def test_truncated_at_the_step_limit(env) -> None:
    env.reset(seed=10001)
    nowhere = {"pose0": ((0.3, 0.45, 0.0), (0, 0, 0, 1)), "pose1": ((0.3, 0.45, 0.0), (0, 0, 0, 1))}
    max_steps = env.unwrapped.task.max_steps
    for step in range(1, max_steps + 1):
        _, reward, terminated, truncated, info = env.step(nowhere)  # an empty corner: nothing moves
        assert not terminated and truncated == (step == max_steps) and not info["is_success"]


GOOD = ((0.5, 0.0, 0.05), (0, 0, 0, 1))
MALFORMED = [
    (None, "action must be a dict with 'pose0' and 'pose1', got NoneType"),
    ({"pose0": GOOD}, "action is missing 'pose1'"),
    ({"pose0": ((0.5, 0, 0.05), (0, 0, 1)), "pose1": GOOD}, "pose0 quaternion must have 4 values"),
    ({"pose0": GOOD, "pose1": np.zeros(7)}, "pose1 must be a pair (xyz, quat_xyzw)"),
    ({"pose0": ((0.5, 0, np.nan), (0, 0, 0, 1)), "pose1": GOOD}, "pose0 contains NaN"),
    ({"pose0": GOOD, "pose1": ((2.0, 0, 0.05), (0, 0, 0, 1))}, "pose1 x=2.000 is outside the workspace"),
    ({"pose0": (("a", 0, 0), (0, 0, 0, 1)), "pose1": GOOD}, "pose0 must be a pair"),
]


def test_malformed_actions_are_clear_errors_before_the_simulator_moves(env) -> None:
    """Each malformed action in turn, in one episode: a clear error, nothing executed; then the episode goes on."""
    env.reset(seed=10001)
    for action, message in MALFORMED:
        with pytest.raises(ActionError) as error:
            env.step(action)
        assert message in str(error.value)
        assert env.unwrapped.sim.steps == 0, message  # nothing was executed
    _, _, _, _, info = env.step(env.unwrapped.oracle_action())
    assert info["steps"] == 1


def test_render_and_raw_images() -> None:
    env = gym.make(env_id(TASK), camera_scale=0.5, raw_images=True, render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=0)
        assert obs in env.observation_space and len(obs["cameras"]) == 3
        assert obs["cameras"][0]["color"].shape == (240, 320, 3) and obs["cameras"][0]["depth"].dtype == np.float32
        frame = env.render()
        assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8 and frame.std() > 0
        np.testing.assert_array_equal(frame, obs["cameras"][0]["color"])  # the front camera
    finally:
        env.close()


def test_bad_settings_are_one_line_errors() -> None:
    with pytest.raises(ConfigError, match="split must be one of train, val, test, got 'dev'"):
        gym.make(env_id(TASK), split="dev")
    env = gym.make(env_id(TASK), camera_scale=0.5)
    try:
        with pytest.raises(ConfigError, match="reset\\(\\) takes no options"):
            env.reset(options={"difficulty": 3})
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("task", TASK_NAMES)
def test_every_task_resets_and_takes_an_expert_step(task) -> None:
    env = gym.make(env_id(task), split="train", camera_scale=0.5)
    try:
        obs, info = env.reset(seed=0)
        assert obs in env.observation_space and info["lang_goal"]
        action = env.unwrapped.oracle_action()
        assert action is not None and action in env.action_space
        obs, reward, terminated, truncated, info = env.step(action)
        assert obs in env.observation_space and reward >= 0 and not truncated
    finally:
        env.close()
