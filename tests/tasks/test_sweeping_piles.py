"""sweeping-piles and separating-piles: scene, zone-metric bookkeeping, language, colour splits, oracle."""

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import apply
from cliport.tasks.colors import COLORS, EVAL_COLORS, TRAIN_COLORS
from cliport.tasks.sweeping_piles import N_CUBES


def _env(name, mode="train"):
    return Environment(EnvConfig.defaults(camera_scale=0.5), task=tasks.make(name, mode))


def _move(env, body, xy):
    p.resetBasePositionAndOrientation(body, (xy[0], xy[1], 0.005), (0, 0, 0, 1), physicsClientId=env.client)


def test_scene_and_zone_reward():
    with _env("sweeping-piles") as env:
        env.reset(0)
        task = env.task
        step = task.goals[0]
        assert len(step.objects) == N_CUBES and step.metric == "zone" and env.objects["rigid"] == step.objects
        assert task.end_effector == "spatula" and task.primitive == "push"
        zone_pose = step.zones[0][0]
        inside = apply(zone_pose, np.array([[0.05, -0.05, 0.0]]))[0]
        outside = apply(zone_pose, np.array([[0.065, 0.0, 0.0]]))[0]
        for b in step.objects[:25]:
            _move(env, b, inside)
        for b in step.objects[25:]:
            _move(env, b, outside)
        assert task.step_reward(step) == pytest.approx(0.5)
        for b in step.objects[25:49]:
            _move(env, b, inside)
        _, info = task.reward()
        assert info["total_reward"] == pytest.approx(0.98) and not task.done()  # 49 of 50 is not a success
        _move(env, step.objects[49], inside)
        _, info = task.reward()
        assert info["total_reward"] == pytest.approx(1.0) and task.done()


def test_same_seed_same_scene_and_push():
    with _env("sweeping-piles") as env:
        runs = []
        for _ in range(2):
            env.reset(6)
            cubes = [
                p.getBasePositionAndOrientation(b, physicsClientId=env.client)[0] for b in env.task.goals[0].objects
            ]
            runs.append((cubes, env.task.oracle_act()))
    assert runs[0] == runs[1]


def test_one_push_gains_reward():
    with _env("sweeping-piles") as env:
        env.reset(0)
        _, reward, _, info = env.step(env.task.oracle_act())
    assert reward > 0 and info["reached"]


def _rgb(color):
    return tuple(c / 255 for c in color)


@pytest.mark.parametrize("unseen", [False, True])
def test_separating_piles_language_and_splits(unseen):
    name = f"separating-piles-{'unseen' if unseen else 'seen'}-colors"
    for mode, seeds in (("train", [0, 2, 4]), ("test", [10001, 10003])):
        palette = EVAL_COLORS if unseen and mode == "test" else TRAIN_COLORS
        with _env(name, mode) as env:
            for seed in seeds:
                env.reset(seed)
                words = env.lang_goal.split()
                assert words[:4] == ["push", "the", "pile", "of"] and words[5:8] == ["blocks", "into", "the"]
                assert words[9] == "square" and len(words) == 10
                assert words[4] in palette and words[8] in palette and words[4] != words[8]
                assert env.task.goals[0].zones[0][1][:2] == (0.15, 0.15)  # the reference's square
                bodies = env.objects["rigid"] + env.objects["fixed"]
                allowed = np.array([_rgb(COLORS[n]) for n in palette])
                for b in bodies:
                    rgb = np.array(p.getVisualShapeData(b, physicsClientId=env.client)[0][7][:3])
                    assert np.min(np.abs(allowed - rgb).max(axis=1)) < 2e-3, f"colour {rgb} is not in the split"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sweeping-piles", "separating-piles-seen-colors"])
@pytest.mark.parametrize("seed", [0, 2])
def test_oracle_completes(name, seed):
    with _env(name) as env:
        episode = run_episode(env, seed, oracle_policy(env))
        assert episode.success and episode.done
        assert env.lang_goal in ("push the pile of blocks into the green square", "done separating the pile.")
