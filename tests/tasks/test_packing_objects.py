import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks.packing_object_set import builtin_objects


@pytest.mark.parametrize("name", ["packing-seen-objects-seq", "packing-unseen-objects-group"])
@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.e2e)])
def test_oracle_completes(name, seed):
    task = tasks.make(name)
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, seed, oracle_policy(env))
    assert episode.success and episode.done
    assert task.lang_goal == "done packing objects."


def test_seq_instructions_follow_template_one_per_step():
    task = tasks.make("packing-seen-objects-seq")
    names = {s.name for s in builtin_objects()}
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, 0, oracle_policy(env), record=True)
    langs = [s["lang_goal"] for s in episode.steps]
    assert len(langs) == len(set(langs)) == task.max_steps - 1
    for lang in langs:
        assert lang.startswith("pack the ") and lang.endswith(" in the brown box")
        assert lang[len("pack the ") : -len(" in the brown box")] in names


def test_group_has_copies_and_distractors():
    task = tasks.make("packing-seen-objects-group")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        env.reset(4)
        step = task.goals[0]
        assert 2 <= len(step.objects) <= 3 and task.max_steps == len(step.objects) + 1
        assert len(env.objects["rigid"]) >= len(step.objects) + 2
        assert task.lang_goal.startswith("pack all the ") and task.lang_goal.endswith(" objects in the brown box")


@pytest.mark.parametrize("name", ["packing-unseen-objects-seq", "packing-unseen-objects-group"])
def test_train_scenes_never_show_unseen_objects(name):
    unseen = {s.name for s in builtin_objects() if s.split == "unseen"}
    seen = {s.name for s in builtin_objects() if s.split == "seen"}
    for mode, allowed in (("train", seen), ("val", unseen)):
        task = tasks.make(name, mode)
        with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
            for seed in (0, 1):
                env.reset(seed)
                spawned = {task.names[b] for b in env.objects["rigid"]}
                assert spawned and spawned <= allowed
