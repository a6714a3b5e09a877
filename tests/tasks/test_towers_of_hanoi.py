import re

import numpy as np
import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.env.transforms import yaw_to_quat
from cliport.tasks.colors import COLORS, EVAL_COLORS, TRAIN_COLORS
from cliport.tasks.towers_of_hanoi import hanoi_moves

UNSEEN_ONLY = [c for c in EVAL_COLORS if c not in TRAIN_COLORS]
ROD = r"(lighter brown side|middle of the stand|darker brown side)"


def test_optimal_solution():
    assert hanoi_moves(3) == [(0, 0, 2), (1, 0, 1), (0, 2, 1), (2, 0, 2), (0, 1, 0), (1, 1, 2), (0, 0, 2)]
    assert len(hanoi_moves(4)) == 15


@pytest.mark.parametrize("name,seed", [("towers-of-hanoi", 0), ("towers-of-hanoi-seq-seen-colors", 2)])
def test_oracle_completes(name, seed):
    task = tasks.make(name)
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env), record=True)
        rings = env.objects["rigid"]
        final = [p.getBasePositionAndOrientation(b, physicsClientId=env.client)[0] for b in rings]
    assert episode.success and episode.done and episode.n_actions == 7
    # all three rings stacked on the far rod, smallest on top
    assert [round(z, 3) for _, _, z in final] == pytest.approx([0.03, 0.02, 0.01], abs=2e-3)
    assert task.lang_goal == ("solve towers of hanoi" if name == "towers-of-hanoi" else "solved towers of hanoi.")


def test_each_move_is_one_seventh_and_yaw_is_ignored():
    task = tasks.make("towers-of-hanoi")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(4)
        assert len(task.goals) == 7 and all(g.share == pytest.approx(1 / 7) for g in task.goals)
        assert all(g.symmetries == [0.0] for g in task.goals)
        first = task.goals[0]
        target = first.targets[0]
        p.resetBasePositionAndOrientation(
            first.objects[0], (target[0][0], target[0][1], 0.05), yaw_to_quat(1.0), physicsClientId=env.client
        )
        env.settle()
        delta, info = task.reward()
        assert delta == pytest.approx(1 / 7) and info["goal_steps_left"] == 6


def test_seq_instructions_follow_the_solution():
    task = tasks.make("towers-of-hanoi-seq-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(6)
        goals = [g.lang_goal for g in task.goals]
        ring_ids = [g.objects[0] for g in task.goals]
    parsed = [re.fullmatch(rf"move the (\w+) ring to the {ROD}", g).groups() for g in goals]
    rods = ("lighter brown side", "middle of the stand", "darker brown side")
    assert [rods.index(r) for _, r in parsed] == [to for _, _, to in hanoi_moves(3)]
    colors = {}
    for body, (color, _) in zip(ring_ids, parsed, strict=True):
        assert colors.setdefault(body, color) == color  # one colour per ring
    assert len(set(colors.values())) == 3 and set(colors.values()) <= set(TRAIN_COLORS)


@pytest.mark.parametrize("variant", ["seen", "unseen"])
def test_train_scenes_never_show_unseen_colors(variant):
    task = tasks.make(f"towers-of-hanoi-seq-{variant}-colors", "train")
    unseen = {COLORS[c] for c in UNSEEN_ONLY}
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (0, 2, 4, 6):
            env.reset(seed)
            rgb = {
                tuple(int(round(c * 255)) for c in shape[7][:3])
                for body in env.objects["rigid"] + env.objects["fixed"]
                for shape in p.getVisualShapeData(body, physicsClientId=env.client)
            }
            assert not rgb & unseen
            assert not any(c in g.lang_goal for g in task.goals for c in UNSEEN_ONLY)


def test_picking_the_top_ring_leaves_the_others():
    """Seed 14 once lifted the middle ring along with the top one (overlapping collision boxes)."""
    task = tasks.make("towers-of-hanoi")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        obs = env.reset(14)
        rings = env.objects["rigid"]
        before = [p.getBasePositionAndOrientation(b, physicsClientId=env.client)[0] for b in rings[1:]]
        _, reward, _, _ = env.step(task.oracle_act(obs))
        after = [p.getBasePositionAndOrientation(b, physicsClientId=env.client)[0] for b in rings[1:]]
    assert reward == pytest.approx(1 / 7)
    after, before = np.array(after), np.array(before)
    assert np.all(np.abs(after[:, 2] - before[:, 2]) < 2e-3)  # still stacked on the stand
    assert np.all(np.linalg.norm(after[:, :2] - before[:, :2], axis=1) < 0.008)  # still around the rod
