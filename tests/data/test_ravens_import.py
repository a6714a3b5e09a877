"""cliport-import of datasets in the reference CLIPort's / Ravens' demos.py layout: written here from our
own simulator's camera images, imported, and served as the same training samples as our own demos of the
same seeds; pickles load safely; every bad file is one error line naming it, and nothing is written."""

from __future__ import annotations

import io
import json
import os
import pickle
import shutil

import numpy as np
import pybullet as p
import pytest
import torch

from cliport import tasks
from cliport.cli.import_demos import entry, main
from cliport.data.dataset import DemoDataset
from cliport.data.episode_io import HEIGHT_UNIT, dataset_dir, episode_path, existing_seeds, load_episode
from cliport.data.generate import DemoConfig, generate
from cliport.data.ravens_import import load_pickle, safe_unpickler
from cliport.data.rollout import oracle_policy, run_episode
from cliport.env.environment import EnvConfig, Environment
from cliport.errors import DemoImportError

TASK = "place-red-in-green"
SCALE = 0.5
FIELDS = ("action", "color", "depth", "info", "reward")


def write_ravens_dataset(folder: str, task: str, seeds: list[int], scale: float) -> str:
    """Our simulator's oracle episodes of ``seeds`` written as the reference's demos.py writes them:
    ``folder/{field}/{index:06d}-{seed}.pkl``, each a pickled per-episode list with one entry per
    observation (color uint8 (T+1, 3, H, W, 3), depth float32 (T+1, 3, H, W), action dicts of numpy
    poses then None, reward 0 then each action's, info dicts with lang_goal and object poses)."""
    for field in FIELDS:
        os.makedirs(os.path.join(folder, field), exist_ok=True)
    env = Environment(EnvConfig.defaults(camera_scale=scale, raw_images=True), task=tasks.make(task, "train"))
    with env:
        for index, seed in enumerate(seeds):
            episode = run_episode(env, seed, oracle_policy(env), record=True)
            assert episode.success, seed
            observations = [s["obs"] for s in episode.steps] + [episode.final_observation]
            objects = {
                body: (*p.getBasePositionAndOrientation(body, physicsClientId=env.client), (0.04, 0.04, 0.04))
                for body in env.objects["rigid"]
            }
            data = {
                "color": np.uint8([[c["color"] for c in o["cameras"]] for o in observations]),
                "depth": np.float32([[c["depth"] for c in o["cameras"]] for o in observations]),
                "action": [
                    {
                        key: (np.asarray(s["action"][key][0]), np.asarray(s["action"][key][1]))
                        for key in ("pose0", "pose1")
                    }
                    for s in episode.steps
                ]
                + [None],
                "reward": [0] + [np.float64(s["reward"]) for s in episode.steps],
                "info": [{**objects, "lang_goal": s["lang_goal"]} for s in episode.steps]
                + [{**objects, "lang_goal": env.lang_goal}],
            }
            for field in FIELDS:
                with open(os.path.join(folder, field, f"{index:06d}-{seed}.pkl"), "wb") as f:
                    pickle.dump(data[field], f)
    return folder


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """Our own demos of the first two train seeds, and the same episodes in the reference's layout."""
    root = tmp_path_factory.mktemp("ravens")
    own = str(root / "own")
    config = DemoConfig.defaults(data_dir=own, workers=1, camera_scale=SCALE, raw_images=False)
    generate(TASK, "train", 2, config, progress=False)
    seeds = existing_seeds(dataset_dir(own, TASK, "train"))
    src = write_ravens_dataset(str(root / f"{TASK}-train"), TASK, seeds, SCALE)
    return own, src, seeds


def _import(src: str, data: str, capsys, *extra: str) -> dict:
    main(["--from", src, "--task", TASK, "--data-dir", data, *extra])
    return json.loads(capsys.readouterr().out)


def test_imported_dataset_gives_our_demos_training_samples(datasets, tmp_path, capsys):
    own, src, seeds = datasets
    data = str(tmp_path / "data")
    summary = _import(src, data, capsys)  # detected as the ravens layout
    assert summary["format"] == "ravens" and summary["seeds"] == seeds
    assert (summary["episodes"], summary["imported"], summary["skipped"]) == (2, 2, 0)
    folder = dataset_dir(data, TASK, "train")
    for seed in seeds:
        ours, imported = (
            load_episode(episode_path(dataset_dir(own, TASK, "train"), seed)),
            load_episode(episode_path(folder, seed)),
        )
        assert len(imported) == len(ours) >= 1
        np.testing.assert_array_equal(imported.color, ours.color)
        np.testing.assert_allclose(imported.height, ours.height, rtol=0, atol=HEIGHT_UNIT)
        np.testing.assert_allclose(imported.pose0, ours.pose0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(imported.pose1, ours.pose1, rtol=0, atol=1e-12)
        np.testing.assert_allclose(imported.reward, ours.reward)
        assert imported.lang_goal == ours.lang_goal
        meta = imported.meta
        assert meta["imported"] is True and meta["format"] == "ravens" and meta["camera_scale"] == SCALE
        assert meta["seed"] == seed and meta["source"].endswith(f"-{seed}.pkl") and meta["total_reward"] > 0.99

    def samples(root: str, augment: bool) -> list[dict]:
        torch.manual_seed(7)  # the augmentation's generator is seeded from torch
        ds = DemoDataset(root, TASK, "train", augment=augment)
        return [ds[i] for i in range(len(ds))]

    for augment in (False, True):
        for a, b in zip(samples(own, augment), samples(data, augment), strict=True):
            np.testing.assert_array_equal(a["color"], b["color"])
            np.testing.assert_allclose(a["height"], b["height"], rtol=0, atol=HEIGHT_UNIT)
            np.testing.assert_allclose(a["pose0"], b["pose0"], rtol=0, atol=1e-9)
            np.testing.assert_allclose(a["pose1"], b["pose1"], rtol=0, atol=1e-9)
            assert (a["lang"], a["task"]) == (b["lang"], b["task"])

    # A training step of a tiny agent sees the same batch, hence the same loss.
    from cliport.agents import make_agent

    torch.manual_seed(0)
    agent = make_agent("transporter_only", {"width": 0.125, "n_rotations": 4, "crop_size": 32})
    losses = []
    for root in (own, data):
        batch = torch.utils.data.default_collate(samples(root, augment=True))
        with torch.no_grad():
            losses.append(float(agent.compute_loss(batch)[0]))
    assert np.isfinite(losses[0]) and losses[0] == losses[1]

    # Re-running resumes: kept files are not rewritten, a removed one is imported again.
    stamp = os.path.getmtime(episode_path(folder, seeds[0]))
    summary = _import(src, data, capsys)
    assert (summary["imported"], summary["skipped"]) == (0, 2)
    os.remove(episode_path(folder, seeds[1]))
    summary = _import(src, data, capsys, "--format", "ravens")
    assert (summary["imported"], summary["skipped"]) == (1, 1)
    assert os.path.getmtime(episode_path(folder, seeds[0])) == stamp


class _Payload:
    """Unpickling this calls ``function(*args)``: what a malicious pickle does."""

    def __init__(self, function, *args):
        self.function, self.args = function, args

    def __reduce__(self):
        return self.function, self.args


def _spoil_truncated(src, name):
    path = os.path.join(src, "color", name)
    with open(path, "rb") as f:
        data = f.read()
    with open(path, "wb") as f:
        f.write(data[: len(data) // 2])


def _spoil_rewrite(field, change):
    def spoil(src, name):
        path = os.path.join(src, field, name)
        with open(path, "rb") as f:
            value = pickle.load(f)
        with open(path, "wb") as f:
            pickle.dump(change(value), f)

    return spoil


def _spoil_with(field, payload):
    def spoil(src, name):
        with open(os.path.join(src, field, name), "wb") as f:
            pickle.dump([{"lang_goal": "x", "evil": payload(src)}], f)

    return spoil


BAD = {
    "truncated pickle": (_spoil_truncated, ["color/", "truncated or not a pickle"]),
    "missing sibling": (lambda src, name: os.remove(os.path.join(src, "reward", name)), ["reward/", "is missing"]),
    "one reward too few": (_spoil_rewrite("reward", lambda r: r[:-1]), ["reward/", "entries but", "action/"]),
    "two cameras": (_spoil_rewrite("color", lambda c: c[:, :2]), ["color/", "3 cameras"]),
    "wrong image size": (_spoil_rewrite("color", lambda c: c[:, :, :200]), ["depth/", "(steps, 3 cameras, H, W)"]),
    "both at a wrong size": (
        lambda src, name: (
            _spoil_rewrite("color", lambda c: c[:, :, :200])(src, name),
            _spoil_rewrite("depth", lambda d: d[:, :, :200])(src, name),
        ),
        ["color/", "200 x 320", "480 x 640"],
    ),
    "pose with 3 rotation numbers": (
        _spoil_rewrite("action", lambda a: [{**a[0], "pose1": (a[0]["pose1"][0], (0, 0, 1))}, *a[1:]]),
        ["action/", "step 0: pose1", "3 and 4 numbers"],
    ),
    "os.system": (
        _spoil_with("info", lambda src: _Payload(os.system, f"touch {os.path.join(src, 'PWNED')}")),
        ["info/", "refused to load", "system", "nothing of the file was run"],
    ),
    "eval": (
        _spoil_with("info", lambda src: _Payload(eval, f"open({os.path.join(src, 'PWNED')!r}, 'w')")),
        ["info/", "refused to load", "builtins.eval"],
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_file_one_error_line_naming_it_and_nothing_written(
    case, datasets, tmp_path, monkeypatch, capsys, one_error_line
):
    _, src, seeds = datasets
    copy = str(tmp_path / f"{TASK}-train")
    shutil.copytree(src, copy)
    name = f"{1:06d}-{seeds[1]}.pkl"  # the second episode: the first one is fine and must not be written either
    spoil, words = BAD[case]
    spoil(copy, name)
    data = str(tmp_path / "data")
    monkeypatch.setattr("sys.argv", ["cliport-import", "--from", copy, "--task", TASK, "--data-dir", data])
    with pytest.raises(SystemExit) as exit_info:
        entry()
    one_error_line(exit_info.value.code, capsys.readouterr().err, name, *words, status=2)
    assert not os.path.exists(os.path.join(copy, "PWNED"))
    assert not os.path.exists(dataset_dir(data, TASK, "train"))


def test_wrong_mode_format_and_bounds_are_one_line(datasets, tmp_path, monkeypatch, capsys, one_error_line):
    _, src, _ = datasets
    data = str(tmp_path / "data")
    cases = [
        (["--from", src, "--mode", "val"], ["seed 0 is not a val seed", "--mode train"]),
        (["--from", src, "--bounds", "0.35", "0.85", "-0.5", "0.5", "0", "0.28"], ["--bounds does not apply"]),
        (["--from", str(tmp_path), "--format", "ravens"], ["no action/, color/, depth/, info/, reward/ folder"]),
    ]
    for argv, words in cases:
        monkeypatch.setattr("sys.argv", ["cliport-import", "--task", TASK, "--data-dir", data, *argv])
        with pytest.raises(SystemExit) as exit_info:
            entry()
        one_error_line(exit_info.value.code, capsys.readouterr().err, *words, status=2)
    assert not os.path.exists(data)


@pytest.mark.parametrize("protocol", range(pickle.HIGHEST_PROTOCOL + 1))
def test_safe_unpickler_builds_arrays_scalars_and_containers(protocol):
    value = [
        np.arange(12, dtype=np.float32).reshape(3, 4),
        np.zeros((2, 2, 3), np.uint8),
        np.float64(0.5),
        np.int64(-3),
        np.dtype("f4"),
        {3: ((0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0)), "lang_goal": "put the red block in the green bowl"},
        {1, 2},
        frozenset({"a"}),
        b"",
        b"\x00\xff",
        bytearray(b"ab"),
        1 + 2j,
        None,
        True,
    ]
    loaded = safe_unpickler(io.BytesIO(pickle.dumps(value, protocol=protocol))).load()
    assert len(loaded) == len(value)
    for a, b in zip(loaded, value, strict=True):
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b)
        else:
            assert type(a) is type(b) and a == b


def test_safe_unpickler_reads_numpy1_names_and_refuses_the_rest(tmp_path):
    # NumPy 1.x wrote numpy.core.multiarray where NumPy 2 writes numpy._core.multiarray (protocol 0 is text).
    old = pickle.dumps(np.arange(3.0), protocol=0).replace(b"numpy._core.", b"numpy.core.")
    assert b"numpy.core.multiarray" in old
    np.testing.assert_array_equal(safe_unpickler(io.BytesIO(old)).load(), np.arange(3.0))
    marker = tmp_path / "ran"
    for payload in (
        _Payload(os.system, f"touch {marker}"),
        _Payload(exec, f"open({str(marker)!r}, 'w')"),
        _Payload(shutil.rmtree, str(tmp_path)),
        io.BytesIO(b"x"),  # any class
    ):
        path = tmp_path / "bad.pkl"
        path.write_bytes(pickle.dumps({"ok": np.zeros(2), "bad": payload}))
        with pytest.raises(DemoImportError, match="refused to load") as info:
            load_pickle(str(path))
        assert str(path) in str(info.value)
        assert not marker.exists() and tmp_path.exists()


def test_reference_cameras_at_any_uniform_scale():
    from cliport.data.ravens_import import cameras_for
    from cliport.env.cameras import realsense_d415

    assert cameras_for((480, 640), "x") == realsense_d415()
    half = cameras_for((240, 320), "x")
    assert [c.image_size for c in half] == [(240, 320)] * 3 and half[0].intrinsics[0] == 225.0
    for shape in ((240, 321), (200, 320), (0, 0)):
        with pytest.raises(DemoImportError, match="not the reference cameras' 480 x 640"):
            cameras_for(shape, "x")
