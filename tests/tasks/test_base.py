"""Reward bookkeeping of the shared goal machinery, tested on hand-placed objects."""

import math

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.env import shapes
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import yaw_to_quat
from cliport.tasks.base import GoalStep, Task, folded_yaw_error


class Scripted(Task):
    """A task whose scene and goals the test sets up by hand."""

    max_steps = 5

    def reset(self, env, rng):
        super().reset(env, rng)


@pytest.fixture(scope="module")
def env():
    e = Environment(EnvConfig.defaults(camera_scale=0.5), task=Scripted())
    yield e
    e.close()


def _block(env, xy, yaw=0.0, size=(0.04, 0.04, 0.04)):
    pose = ((xy[0], xy[1], size[2] / 2), yaw_to_quat(yaw))
    return env.add_object(shapes.box(env.client, size, pose, color=(200, 50, 50)))


def _move(env, body, xy, yaw=0.0):
    p.resetBasePositionAndOrientation(body, (xy[0], xy[1], 0.02), yaw_to_quat(yaw), physicsClientId=env.client)


def test_folded_yaw_error():
    assert folded_yaw_error(math.radians(95), 0.0, math.pi / 2) == pytest.approx(math.radians(5))
    assert folded_yaw_error(math.radians(-170), math.radians(170), 2 * math.pi) == pytest.approx(math.radians(20))
    assert folded_yaw_error(math.radians(181), 0.0, math.pi) == pytest.approx(math.radians(1))


def test_partial_credit_banking_and_done(env):
    env.reset(0)
    task = env.task
    a, b = _block(env, (0.4, 0.2)), _block(env, (0.4, -0.2))
    targets = [((0.6, 0.2, 0.02), (0, 0, 0, 1)), ((0.6, -0.2, 0.02), (0, 0, 0, 1))]
    task.add_goal(GoalStep([a, b], np.eye(2), targets, share=0.5))
    c = _block(env, (0.3, 0.0))
    task.add_goal(GoalStep([c], np.ones((1, 1)), [((0.5, 0.0, 0.02), (0, 0, 0, 1))], share=0.5))
    assert task.reward()[0] == pytest.approx(0.0)
    _move(env, a, (0.605, 0.2))  # within 1 cm
    reward, info = task.reward()
    assert reward == pytest.approx(0.25) and info["goal_steps_left"] == 2
    assert task.reward()[0] == pytest.approx(0.0)  # rewards are deltas
    _move(env, b, (0.6, -0.189))  # 1.1 cm away: not matched
    assert task.reward()[0] == pytest.approx(0.0)
    _move(env, b, (0.6, -0.205))
    reward, info = task.reward()
    assert reward == pytest.approx(0.25) and info["goal_steps_left"] == 1  # first step banked
    _move(env, a, (0.4, 0.2))  # a banked step is not taken back
    assert task.reward()[0] == pytest.approx(0.0) and not task.done()
    _move(env, c, (0.5, 0.0))
    reward, info = task.reward()
    assert reward == pytest.approx(0.5) and info["total_reward"] == pytest.approx(1.0) and task.done()


def test_one_goal_step_banked_per_action_as_the_reference(env):
    """A later step met first is credited only once it is the current step, at the next call (action)."""
    env.reset(0)
    task = env.task
    a, b, c = _block(env, (0.4, 0.2)), _block(env, (0.4, -0.2)), _block(env, (0.3, 0.0))
    for body, xy in ((a, (0.6, 0.2)), (b, (0.6, -0.2)), (c, (0.5, 0.0))):
        task.add_goal(GoalStep([body], np.ones((1, 1)), [((*xy, 0.02), (0, 0, 0, 1))], share=1 / 3))
    _move(env, c, (0.5, 0.0))  # the third step's object first: nothing, the first step is current
    reward, info = task.reward()
    assert reward == pytest.approx(0.0) and info["goal_steps_left"] == 3
    _move(env, b, (0.6, -0.2))  # the second's: still nothing
    assert task.reward()[0] == pytest.approx(0.0)
    _move(env, a, (0.6, 0.2))  # all three placed: this action banks the first step only
    reward, info = task.reward()
    assert reward == pytest.approx(1 / 3) and info["goal_steps_left"] == 2 and not task.done()
    reward, info = task.reward()  # the next action banks the second, already met
    assert reward == pytest.approx(1 / 3) and info["goal_steps_left"] == 1
    reward, info = task.reward()
    assert reward == pytest.approx(1 / 3) and info["total_reward"] == pytest.approx(1.0) and task.done()


def test_symmetric_yaw_and_rotation_flag(env):
    env.reset(0)
    task = env.task
    block = _block(env, (0.5, 0.1), yaw=math.radians(100))
    target = [((0.5, 0.1, 0.02), (0, 0, 0, 1))]
    step = GoalStep([block], np.ones((1, 1)), target, share=1.0, symmetries=[math.pi / 2], rotations=True)
    assert task.is_match(step, 0, 0)  # 100 deg folds to 10 deg for a 90 deg symmetry
    _move(env, block, (0.5, 0.1), yaw=math.radians(70))
    assert not task.is_match(step, 0, 0)  # 20 deg off
    step.symmetries = [0.0]
    assert task.is_match(step, 0, 0)  # symmetry 0: yaw ignored
    step.symmetries, step.rotations = [2 * math.pi], False
    assert task.is_match(step, 0, 0)  # rotation does not matter for this step


def test_targets_used_once_unless_replace(env):
    env.reset(0)
    task = env.task
    a, b = _block(env, (0.5, 0.1)), _block(env, (0.5, 0.3))
    target = [((0.5, 0.1, 0.02), (0, 0, 0, 1)), ((0.5, 0.3, 0.02), (0, 0, 0, 1))]
    step = GoalStep([a, b], np.ones((2, 2)), target, share=1.0)
    assert sorted(task.matched_pairs(step)) == [(0, 0), (1, 1)]
    _move(env, b, (0.5, 0.105))  # b now sits on a's target (blocks overlap: metric only)
    assert len(task.matched_pairs(step)) == 1
    step.replace = True
    assert len(task.matched_pairs(step)) == 2


def test_zone_fraction(env):
    env.reset(0)
    task = env.task
    body = _block(env, (0.5, 0.0), size=(0.08, 0.04, 0.04))  # 2 cm grid: 5 x 3 x 3 points
    zone = (((0.52, 0.0, 0.0), (0, 0, 0, 1)), (0.08, 0.2, 0.0))  # covers x in (0.48, 0.56)
    step = GoalStep([body], np.ones((1, 1)), [zone[0]], share=1.0, metric="zone", zones=[zone])
    assert task.zone_fraction(step, body) == pytest.approx(3 / 5)
    assert task.step_reward(step) == pytest.approx(3 / 5)


def test_registry_errors():
    assert "place-red-in-green" in tasks.names()
    with pytest.raises(KeyError, match="did you mean place-red-in-green"):
        tasks.make("place-red-in-gren")
    with pytest.raises(ValueError, match="mode"):
        tasks.make("place-red-in-green", mode="training")


def test_splits_register_both_colour_sets_as_picklable_classes():
    import pickle

    seen, unseen = tasks.make("towers-of-hanoi-seq-seen-colors"), tasks.make("towers-of-hanoi-seq-unseen-colors")
    assert (seen.unseen, unseen.unseen) == (False, True)
    assert type(unseen).__name__ == "TowersOfHanoiSeqUnseenColors" and type(seen).__bases__ == type(unseen).__bases__
    assert pickle.loads(pickle.dumps(type(unseen))) is type(unseen)


def test_groups_name_registered_tasks():
    groups = tasks.groups()
    assert len(groups["multi-ravens"]) == 10 and len(groups["multi-language-conditioned"]) == 18
    for members in groups.values():
        assert set(members) <= set(tasks.names())
    assert tasks.resolve("multi-language-conditioned-seen")[0] == "align-rope"
    with pytest.raises(KeyError, match="multi-task group"):
        tasks.make("multi-ravens")


def test_recorded_size_drives_zone_fraction_and_oracle_skips_packed_objects(env):
    env.reset(0)
    task = env.task
    inside = _block(env, (0.5, 0.0))
    outside = _block(env, (0.35, 0.3))
    zone = (((0.5, 0.0, 0.0), (0, 0, 0, 1)), (0.1, 0.1, 0.0))
    targets = [((0.5, 0.0, 0.02), (0, 0, 0, 1)), ((0.52, 0.02, 0.02), (0, 0, 0, 1))]
    step = GoalStep([inside, outside], np.eye(2), targets, share=1.0, metric="zone", zones=[zone])
    task.add_goal(step)
    task.set_object_size(inside, (0.2, 0.04, 0.04))  # pretend it is long: half of it sticks out
    assert task.zone_fraction(step, inside) == pytest.approx(5 / 11)
    task.object_sizes.clear()
    assert task.zone_fraction(step, inside) == 1.0
    action = task.oracle_act()
    assert action is not None and np.linalg.norm(np.subtract(action["pose0"][0][:2], (0.35, 0.3))) < 0.03
