import json

import numpy as np
import pytest

from cliport import tasks
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.tasks import packing_object_set as objset

CUBE_OBJ = """v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""


def test_builtin_set_is_named_and_split():
    specs = objset.builtin_objects()
    names = [s.name for s in specs]
    assert len(names) >= 30 and len(set(names)) == len(names)
    seen = [s for s in specs if s.split == "seen"]
    assert 0.6 <= len(seen) / len(specs) <= 0.7
    assert objset.split_objects(specs, "train", unseen=True) == seen
    assert all(s.split == "unseen" for s in objset.split_objects(specs, "test", unseen=True))
    assert objset.split_objects(specs, "test", unseen=False) == seen


def test_every_builtin_object_fits_a_cell():
    for spec in objset.builtin_objects():
        _, half = objset.centred_parts(spec)
        assert max(half[0], half[1]) * 2 < 0.075, spec.name  # fits a cell (side >= 8.5 cm) with room
        assert 0.002 < half[2] < 0.04, spec.name


def _write_cube(path):
    path.mkdir(parents=True)
    (path / "model.obj").write_text(CUBE_OBJ)


def test_user_folder_of_named_meshes(tmp_path):
    for name in ("rubber_duck", "soup_can", "tea_box"):
        _write_cube(tmp_path / name)
    specs = objset.load_object_folder(str(tmp_path))
    assert [s.name for s in specs] == ["rubber duck", "soup can", "tea box"]
    assert [s.split for s in specs] == ["seen", "seen", "unseen"]
    _, half = objset.centred_parts(specs[0])
    assert np.hypot(half[0], half[1]) * 2 == pytest.approx(0.065)


def test_user_manifest(tmp_path):
    _write_cube(tmp_path / "meshes" / "a")
    manifest = {
        "objects": [
            {"name": "pencil case", "mesh": "meshes/a/model.obj", "split": "unseen", "size": 0.05},
            {"name": "tin", "mesh": "meshes/a/model.obj", "color": [10, 20, 30]},
        ]
    }
    (tmp_path / "objects.json").write_text(json.dumps(manifest))
    specs = objset.load_object_folder(str(tmp_path))
    assert [(s.name, s.split) for s in specs] == [("pencil case", "unseen"), ("tin", "seen")]
    assert specs[1].color == (10, 20, 30)
    bad = {"objects": [{"name": "x", "mesh": "meshes/a/model.obj", "split": "maybe"}]}
    (tmp_path / "objects.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="split"):
        objset.load_object_folder(str(tmp_path))


def test_user_set_is_used_by_the_tasks(tmp_path, monkeypatch):
    for name in ("block_a", "block_b", "block_c", "block_d", "block_e", "block_f"):
        _write_cube(tmp_path / name)
    monkeypatch.setenv(objset.OBJECTS_ENV_VAR, str(tmp_path))
    task = tasks.make("packing-seen-objects-seq")
    with Environment(EnvConfig.defaults(camera_scale=0.5), task=task) as env:
        episode = run_episode(env, 0, oracle_policy(env), record=True)
    assert episode.success
    assert episode.steps[0]["lang_goal"].startswith("pack the block ")
