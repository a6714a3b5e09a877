"""assembling-kits and assembling-kits-seq-{seen,unseen}-colors: oracle, rewards, language, splits."""

import math
import re

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import quat_to_yaw
from cliport.tasks.assembling_kits import spatial_word
from cliport.tasks.colors import EVAL_COLORS, TRAIN_COLORS
from cliport.tasks.kit_shapes import SHAPES

SEQ = ["assembling-kits-seq-seen-colors", "assembling-kits-seq-unseen-colors"]
LABELS = "|".join(re.escape(s.label) for s in SHAPES)
INSTRUCTION = re.compile(rf"put the (\w+) ({LABELS}) in the ((?:top|bottom|left|right|middle) )?({LABELS}) hole")


@pytest.fixture
def env():
    with Environment(EnvConfig.defaults(camera_scale=0.5)) as e:
        yield e


@pytest.mark.parametrize(
    "name,seed",
    [("assembling-kits", 0), pytest.param("assembling-kits", 2, marks=pytest.mark.e2e), (SEQ[0], 0), (SEQ[1], 2)],
)
def test_oracle_completes(env, name, seed):
    task = tasks.make(name)
    env.set_task(task)
    episode = run_episode(env, seed, oracle_policy(env), record=True)
    assert episode.success and episode.done
    assert episode.n_actions == 5
    np.testing.assert_allclose([s["reward"] for s in episode.steps], 0.2, atol=1e-6)  # 1/5 per object
    for s in episode.steps:  # the oracle splits each turn between pick and place (wrist stays off +-pi)
        assert abs(quat_to_yaw(s["action"]["pose0"][1])) <= math.pi / 2 + 1e-6
        assert abs(quat_to_yaw(s["action"]["pose1"][1])) <= math.pi / 2 + 1e-6
    if name == "assembling-kits":
        assert {s["lang_goal"] for s in episode.steps} == {"put all the blocks inside the holes they fit in"}
    else:
        assert task.lang_goal == "done assembling kit."
        for step in episode.steps:
            match = INSTRUCTION.fullmatch(step["lang_goal"])
            assert match and match.group(2) == match.group(4), step["lang_goal"]


def test_scene_and_goals(env):
    task = tasks.make("assembling-kits")
    env.set_task(task)
    env.reset(4)
    assert len(env.objects["fixed"]) == 1 and len(env.objects["rigid"]) == 5
    lo, hi = (np.asarray(v) for v in p.getAABB(env.objects["fixed"][0], physicsClientId=env.client))
    assert hi[2] - lo[2] == pytest.approx(0.005, abs=0.001)
    assert 0.278 <= (hi - lo)[:2].max() <= 0.345  # a 0.28 x 0.2 board at any yaw
    (step,) = task.goals
    assert step.rotations and step.metric == "pose" and step.share == 1.0
    shapes_of = [task.object_shapes[b] for b in step.objects]
    assert step.symmetries == [SHAPES[s].symmetry for s in shapes_of]
    expected = np.equal.outer(shapes_of, shapes_of)  # any hole of the object's shape
    assert np.array_equal(step.matches, expected)
    assert all(s in range(14) for s in shapes_of)


def test_seq_goal_steps_name_one_object_each(env):
    task = tasks.make(SEQ[0])
    env.set_task(task)
    env.reset(6)
    assert len(task.goals) == 5 and task.max_steps == 5
    for step in task.goals:
        (body,) = step.objects
        match = INSTRUCTION.fullmatch(step.lang_goal)
        assert match is not None
        assert match.group(1) == task.object_colors[body]
        assert match.group(2) == SHAPES[task.object_shapes[body]].label
        assert step.share == pytest.approx(0.2) and step.rotations
    assert task.lang_goal == task.goals[0].lang_goal


def test_spatial_word():
    pos = [np.array(v) for v in [(0.4, 0.0), (0.5, 0.0), (0.45, -0.2), (0.45, 0.2), (0.45, 0.0)]]
    assert spatial_word(0, [3, 4, 5, 6, 7], pos) == ""
    assert spatial_word(0, [3, 3, 5, 6, 7], pos) == "top "
    assert spatial_word(1, [3, 3, 5, 6, 7], pos) == "bottom "
    assert spatial_word(2, [1, 2, 3, 3, 7], pos) == "left "
    assert spatial_word(3, [1, 2, 3, 3, 7], pos) == "right "
    assert spatial_word(4, [1, 2, 3, 3, 3], pos) == "middle "


@pytest.mark.parametrize("name", ["assembling-kits", *SEQ])
def test_train_scenes_never_use_unseen_attributes(env, name):
    task = tasks.make(name, "train")
    env.set_task(task)
    for seed in (0, 2, 4):
        env.reset(seed)
        assert set(task.object_colors.values()) <= set(TRAIN_COLORS)
        assert len(set(task.object_colors.values())) == 5
        assert set(task.object_shapes.values()) <= set(range(14))


def test_eval_scenes_use_unseen_shapes_and_colors(env):
    task = tasks.make(SEQ[1], "val")
    env.set_task(task)
    env.reset(1)
    assert set(task.object_colors.values()) <= set(EVAL_COLORS)
    assert set(task.object_shapes.values()) <= set(range(14, 20))
    seen = tasks.make(SEQ[0], "test")
    env.set_task(seen)
    env.reset(10001)
    assert set(seen.object_colors.values()) <= set(TRAIN_COLORS)
    assert set(seen.object_shapes.values()) <= set(range(14, 20))
