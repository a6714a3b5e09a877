import pybullet as p
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.colors import COLORS, EVAL_COLORS, TRAIN_COLORS

UNSEEN_ONLY = [c for c in EVAL_COLORS if c not in TRAIN_COLORS]
TEMPLATE = "put the {} blocks in a {} bowl"


def scene_colors(env) -> set[tuple[int, int, int]]:
    return {
        tuple(int(round(c * 255)) for c in shape[7][:3])
        for body in env.objects["rigid"] + env.objects["fixed"]
        for shape in p.getVisualShapeData(body, physicsClientId=env.client)
    }


@pytest.mark.parametrize("name,seed", [("put-block-in-bowl-seen-colors", 0), ("put-block-in-bowl-unseen-colors", 4)])
def test_oracle_completes(name, seed):
    task = tasks.make(name)
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env), record=True)
    assert episode.success and episode.done
    first = episode.steps[0]["lang_goal"]
    assert all(s["lang_goal"] == first for s in episode.steps)
    assert task.lang_goal == "done placing blocks in bowls."


def test_instruction_and_step_budget():
    task = tasks.make("put-block-in-bowl-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (0, 2, 4, 6):
            env.reset(seed)
            step = task.goals[0]
            assert task.max_steps == len(step.objects) + 1
            assert len(step.objects) <= len(step.targets) <= 3
            names = {rgb: name for name, rgb in COLORS.items()}
            pick, place = (
                names[tuple(round(c * 255) for c in p.getVisualShapeData(b, physicsClientId=env.client)[0][7][:3])]
                for b in (step.objects[0], env.objects["fixed"][0])
            )
            assert task.lang_goal == TEMPLATE.format(pick, place)


def test_two_blocks_in_one_bowl_count_once():
    task = tasks.make("put-block-in-bowl-seen-colors")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        seed = next(s for s in range(0, 40, 2) if env.reset(s) is not None and len(task.goals[0].objects) >= 2)
        step = task.goals[0]
        bowl = step.targets[0]
        for body in step.objects[:2]:
            p.resetBasePositionAndOrientation(
                body, (bowl[0][0], bowl[0][1], 0.03), (0, 0, 0, 1), physicsClientId=env.client
            )
        assert task.step_reward(step) == pytest.approx(1 / len(step.objects)), seed


@pytest.mark.parametrize("variant", ["seen", "unseen"])
def test_train_scenes_never_show_unseen_colors(variant):
    task = tasks.make(f"put-block-in-bowl-{variant}-colors", "train")
    unseen = {COLORS[c] for c in UNSEEN_ONLY}
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in range(0, 10, 2):
            env.reset(seed)
            assert not scene_colors(env) & unseen
            assert not any(c in task.lang_goal for c in UNSEEN_ONLY)


def test_unseen_variant_uses_eval_colors_in_test_mode():
    task = tasks.make("put-block-in-bowl-unseen-colors", "test")
    allowed = {COLORS[c] for c in EVAL_COLORS}
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        for seed in (10001, 10003, 10005):
            env.reset(seed)
            assert scene_colors(env) <= allowed
