import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS
from cliport.tasks.packing_assets import kd_split


def test_kd_split_covers_the_box_with_cells_of_min_side():
    rng = np.random.default_rng(3)
    cells = kd_split(rng, (0.27, 0.19), 0.05)
    assert sum(float(np.prod(s)) for _, s in cells) == pytest.approx(0.27 * 0.19)
    assert all(np.all(s >= 0.05 - 1e-9) for _, s in cells)
    assert len(cells) > 1


@pytest.mark.parametrize("seed", [0, pytest.param(4, marks=pytest.mark.e2e)])
def test_packing_boxes_oracle_completes(seed):
    task = tasks.make("packing-boxes")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env))
    assert episode.success and episode.done


def test_packing_boxes_zone_reward_is_a_fraction_of_boxes_inside():
    task = tasks.make("packing-boxes")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(0)
        step = task.goals[0]
        assert step.metric == "zone" and step.share == 1.0
        assert all(task.zone_fraction(step, b) == 0.0 for b in step.objects)
        assert task.reward()[0] == 0.0
        obs, reward, done, _ = env.step(task.oracle_act())
        assert reward == pytest.approx(1.0 / len(step.objects), abs=0.02)
        assert not done or len(step.objects) == 1


def test_pairs_instruction_and_colors():
    task = tasks.make("packing-boxes-pairs-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, 2, oracle_policy(env), record=True)
        assert episode.success
        first = episode.steps[0]["lang_goal"]
        words = first.split()
        assert first == f"pack all the {words[3]} and {words[5]} blocks into the brown box"
        assert words[3] in TRAIN_COLORS and words[5] in TRAIN_COLORS and words[3] != words[5]
        assert all(s["lang_goal"] == first for s in episode.steps)
        assert task.lang_goal == "done packing blocks."


@pytest.mark.parametrize("mode", ["train", "test"])
def test_pairs_unseen_split(mode):
    task = tasks.make("packing-boxes-pairs-unseen-colors", mode)
    allowed = set(TRAIN_COLORS if mode == "train" else EVAL_COLORS)
    only_other = set(EVAL_COLORS if mode == "train" else TRAIN_COLORS) - allowed
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (0, 1):
            env.reset(seed)
            words = task.lang_goal.split()
            assert {words[3], words[5]} <= allowed
            boxes = env.objects["rigid"]
            assert len(boxes) == len(task.goals[0].objects) + 4
            colors = {_color_name(env, b) for b in boxes}
            assert colors <= allowed and not colors & only_other


def _color_name(env, body):
    import pybullet as p

    from cliport.tasks.colors import COLORS

    rgba = p.getVisualShapeData(body, physicsClientId=env.client)[0][7]
    rgb = np.array(rgba[:3]) * 255
    return min(COLORS, key=lambda c: np.abs(np.array(COLORS[c]) - rgb).sum())


def test_pairs_box_stacked_on_another_does_not_count_in_full():
    task = tasks.make("packing-boxes-pairs-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(2)
        step = task.goals[0]
        (low, quat), own = step.targets[0], step.targets[1]
        a, b = step.objects[:2]
        p.resetBasePositionAndOrientation(a, low, quat, physicsClientId=env.client)
        p.resetBasePositionAndOrientation(b, (low[0], low[1], low[2] + 0.05), quat, physicsClientId=env.client)
        assert task.zone_fraction(step, a) == 1.0
        assert task.zone_fraction(step, b) < 1.0
        p.resetBasePositionAndOrientation(b, *own, physicsClientId=env.client)
        assert task.zone_fraction(step, b) == 1.0
