"""cliport-import of datasets in the reference CLIPort's / Ravens' demos.py layout."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import torch

from cliport.cli import import_demos as import_cli
from cliport.cli.common import run_cli
from cliport.data.episode_io import episode_path, load_episode

TASK = "place-red-in-green"


def write_ravens_split(root: str, task: str, mode: str, seeds: list[int]) -> str:
    """What the reference's demos.py writes for these seeds of our simulator (full-resolution cameras):
    ``{task}-{mode}/{action,color,depth,info,reward}/{index:06d}-{seed}.pkl``."""
    from cliport import tasks
    from cliport.data.rollout import oracle_policy, run_episode
    from cliport.env.environment import EnvConfig, Environment

    folder = os.path.join(root, f"{task}-{mode}")
    with Environment(EnvConfig.defaults(raw_images=True), task=tasks.make(task, mode)) as env:
        for index, seed in enumerate(seeds):
            episode = run_episode(env, seed, oracle_policy(env), record=True)
            observations = [s["obs"] for s in episode.steps] + [episode.final_observation]
            fields = {
                "color": np.uint8([[c["color"] for c in o["cameras"]] for o in observations]),
                "depth": np.float32([[c["depth"] for c in o["cameras"]] for o in observations]),
                "action": [s["action"] for s in episode.steps] + [None],
                "reward": [0.0] + [s["reward"] for s in episode.steps],
                "info": [{"lang_goal": s["lang_goal"], 5: ((0.5, 0.1, 0.02), (0, 0, 0, 1), (0.04, 0.04, 0.04))}
                         for s in episode.steps] + [{"lang_goal": env.lang_goal}],  # fmt: skip
            }
            for name, data in fields.items():
                os.makedirs(os.path.join(folder, name), exist_ok=True)
                with open(os.path.join(folder, name, f"{index:06d}-{seed}.pkl"), "wb") as f:
                    pickle.dump(data, f)
    return folder


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    capsys.readouterr()
    code = 0
    try:
        run_cli(lambda: import_cli.main(argv))
    except SystemExit as stop:
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_an_imported_dataset_trains_on_the_same_samples_as_our_own_demos(tmp_path, capsys) -> None:
    from cliport.data.dataset import DemoDataset
    from cliport.data.generate import DemoConfig, generate

    ours = str(tmp_path / "ours")
    generate(TASK, "train", 2, DemoConfig.defaults(data_dir=ours, camera_scale=1.0), progress=False)
    seeds = sorted(int(f[:6]) for f in os.listdir(os.path.join(ours, f"{TASK}-train")) if f.endswith(".npz"))
    split = write_ravens_split(str(tmp_path / "ravens"), TASK, "train", seeds)
    imported = str(tmp_path / "imported")
    code, out, err = _cli(["--from", split, "--data-dir", imported], capsys)  # format and task: auto
    assert code == 0, err
    summary = json.loads(out)
    assert summary["format"] == "ravens" and summary["task"] == TASK and summary["mode"] == "train"
    assert summary["imported"] == 2 and summary["seeds"] == seeds
    for seed in seeds:
        a = load_episode(episode_path(os.path.join(ours, f"{TASK}-train"), seed))
        b = load_episode(episode_path(os.path.join(imported, f"{TASK}-train"), seed))
        assert np.array_equal(a.color, b.color) and np.array_equal(a.height, b.height)  # the same fusion
        assert np.array_equal(a.pose0, b.pose0) and np.array_equal(a.pose1, b.pose1)
        assert np.array_equal(a.reward, b.reward) and a.lang_goal == b.lang_goal
        assert b.meta["format"] == "ravens" and b.meta["imported"]
    datasets = [DemoDataset(root, TASK, "train", 2, seed=3) for root in (ours, imported)]
    assert len(datasets[0]) == len(datasets[1]) >= 2
    for i in range(len(datasets[0])):  # augmented samples, seeded alike
        x, y = datasets[0][i], datasets[1][i]
        for key, value in x.items():
            if isinstance(value, torch.Tensor | np.ndarray):
                assert np.array_equal(np.asarray(value), np.asarray(y[key])), key
            else:
                assert value == y[key], key
    # A re-run keeps what was imported.
    code, out, _ = _cli(["--from", split, "--data-dir", imported, "--format", "ravens"], capsys)
    assert code == 0 and json.loads(out)["skipped"] == 2


def _tiny_split(root, n_actions: int = 1) -> str:
    folder = os.path.join(str(root), f"{TASK}-train")
    pose = ((0.5, 0.0, 0.02), (0.0, 0.0, 0.0, 1.0))
    fields = {
        "color": np.zeros((n_actions + 1, 3, 480, 640, 3), np.uint8),
        "depth": np.ones((n_actions + 1, 3, 480, 640), np.float32),
        "action": [{"pose0": pose, "pose1": pose}] * n_actions + [None],
        "reward": [0.0] + [1.0 / n_actions] * n_actions,
        "info": [{"lang_goal": "put the red blocks in a green bowl"}] * (n_actions + 1),
    }
    for name, data in fields.items():
        os.makedirs(os.path.join(folder, name), exist_ok=True)
        with open(os.path.join(folder, name, "000000-0.pkl"), "wb") as f:
            pickle.dump(data, f)
    return folder


class _RunsCode:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _one_line(code: int, err: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, err)
    return lines[0]


def test_every_bad_file_is_one_line_and_nothing_is_written(tmp_path, capsys) -> None:
    data = str(tmp_path / "data")

    def import_error(split: str) -> str:
        message = _one_line(*_cli(["--from", split, "--data-dir", data], capsys)[::2])
        assert not os.path.exists(os.path.join(data, f"{TASK}-train", "000000.npz"))
        return message

    split = _tiny_split(tmp_path / "evil")
    marker = tmp_path / "ran"
    with open(os.path.join(split, "reward", "000000-0.pkl"), "wb") as f:
        pickle.dump([0.0, _RunsCode(str(marker))], f)
    msg = import_error(split)
    assert "reward/000000-0.pkl names posix.system" in msg and not marker.exists()

    split = _tiny_split(tmp_path / "cut")
    path = os.path.join(split, "color", "000000-0.pkl")
    with open(path, "rb") as f:
        head = f.read(1000)
    with open(path, "wb") as f:
        f.write(head)
    assert f"{path} is truncated or not a pickle" in import_error(split)

    split = _tiny_split(tmp_path / "missing")
    os.remove(os.path.join(split, "info", "000000-0.pkl"))
    assert "info/000000-0.pkl is missing" in import_error(split)

    split = _tiny_split(tmp_path / "counts")
    with open(os.path.join(split, "reward", "000000-0.pkl"), "wb") as f:
        pickle.dump([0.0], f)
    assert "reward/000000-0.pkl has 1 entries but" in import_error(split)

    split = _tiny_split(tmp_path / "shape")
    with open(os.path.join(split, "depth", "000000-0.pkl"), "wb") as f:
        pickle.dump(np.ones((2, 3, 240, 320), np.float32), f)
    assert "must hold float depth images (steps, 3, 480, 640)" in import_error(split)

    split = _tiny_split(tmp_path / "named" / "not-a-split")
    os.rename(split, os.path.join(os.path.dirname(split), "somewhere"))
    assert "pass --task and --mode" in import_error(os.path.join(os.path.dirname(split), "somewhere"))
