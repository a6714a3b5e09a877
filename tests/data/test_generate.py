import json
import os

import numpy as np
import pytest

from cliport.cli import demos as demos_cli
from cliport.data.episode_io import EpisodeFileError, existing_seeds, load_episode
from cliport.data.generate import DemoConfig, generate
from cliport.env.environment import expected_renderer

TASKS = ["place-red-in-green", "block-insertion"]


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("demos"))
    config = DemoConfig.defaults(data_dir=root, workers=2, camera_scale=0.5)
    summaries = [generate(task, "train", 2, config, progress=False) for task in TASKS]
    return root, summaries


def test_two_tasks_two_workers(data_dir):
    root, summaries = data_dir
    for task, summary in zip(TASKS, summaries, strict=True):
        folder = os.path.join(root, f"{task}-train")
        seeds = existing_seeds(folder)
        assert len(seeds) == 2 and all(s % 2 == 0 for s in seeds)
        assert summary["saved"] == 2 and summary["mb_per_step"] < 0.1
        with open(os.path.join(folder, "summary.json")) as f:
            assert json.load(f)["saved"] == 2
        ep = load_episode(os.path.join(folder, f"{seeds[0]:06d}.npz"))
        assert ep.color.shape[1:] == (320, 160, 3) and ep.color.dtype == np.uint8
        assert ep.height.shape[1:] == (320, 160) and ep.pose0.shape[1] == 7
        assert ep.meta["task"] == task and ep.meta["seed"] == seeds[0] and ep.meta["total_reward"] > 0.99
        assert ep.meta["renderer"] == summary["renderer"] == expected_renderer("auto")
        assert len(ep.lang_goal) == len(ep)


def test_resume_regenerates_only_the_missing_episode(data_dir):
    root, _ = data_dir
    folder = os.path.join(root, "place-red-in-green-train")
    seeds = existing_seeds(folder)
    keep = os.path.join(folder, f"{seeds[0]:06d}.npz")
    before = os.path.getmtime(keep)
    os.remove(os.path.join(folder, f"{seeds[1]:06d}.npz"))
    with open(os.path.join(folder, "x.npz.tmp-123"), "w") as f:
        f.write("half-written")
    summary = generate(
        "place-red-in-green", "train", 2, DemoConfig.defaults(data_dir=root, camera_scale=0.5), progress=False
    )
    assert summary["saved"] == 1 and summary["skipped_existing"] == 1
    assert existing_seeds(folder) == seeds
    assert os.path.getmtime(keep) == before
    assert not [f for f in os.listdir(folder) if ".tmp-" in f]


def test_complete_folder_starts_no_simulator(data_dir, monkeypatch):
    root, _ = data_dir
    config = DemoConfig.defaults(data_dir=root, camera_scale=0.5)
    generate("block-insertion", "train", 2, config, progress=False)

    def no_simulator(*args):
        raise AssertionError("a simulator was started for a complete folder")

    monkeypatch.setattr("cliport.data.generate.init_worker", no_simulator)
    summary = generate("block-insertion", "train", 2, config, progress=False)
    assert summary["saved"] == 0 and summary["skipped_existing"] == 2


def test_truncated_file_is_reported_by_name(data_dir, tmp_path):
    root, _ = data_dir
    folder = os.path.join(root, "block-insertion-train")
    src = os.path.join(folder, f"{existing_seeds(folder)[0]:06d}.npz")
    bad = tmp_path / "000000.npz"
    bad.write_bytes(open(src, "rb").read()[:5000])
    with pytest.raises(EpisodeFileError, match=str(bad)):
        load_episode(str(bad))


def test_cli_reports_bad_input(capsys, one_error_line):
    with pytest.raises(SystemExit) as exit_info:
        demos_cli.run_cli(lambda: demos_cli.main(["--task", "no-such-task", "--n", "1"]))
    one_error_line(exit_info.value.code, capsys.readouterr().err, "unknown task 'no-such-task'", status=2)


def test_rerun_regenerates_truncated_and_foreign_files(data_dir):
    root, _ = data_dir
    folder = os.path.join(root, "block-insertion-train")
    seeds = existing_seeds(folder)
    paths = [os.path.join(folder, f"{s:06d}.npz") for s in seeds]
    with open(paths[0], "r+b") as f:
        f.truncate(os.path.getsize(paths[0]) // 2)
    with open(paths[1], "wb") as f:
        f.write(np.random.default_rng(0).bytes(4096))
    summary = generate(
        "block-insertion", "train", 2, DemoConfig.defaults(data_dir=root, workers=1, camera_scale=0.5), progress=False
    )
    assert summary["corrupt_removed"] == seeds and summary["regenerated"] == 2 and summary["saved"] == 2
    assert existing_seeds(folder) == seeds
    for path, seed in zip(paths, seeds, strict=True):
        assert load_episode(path).meta["seed"] == seed


LESSON = "put-one-block-in-bowl-seen-colors"


def test_every_instruction_records_the_variants_and_rerecords_older_files(tmp_path):
    root = str(tmp_path)
    folder = os.path.join(root, f"{LESSON}-train")
    plain = DemoConfig.defaults(data_dir=root, camera_scale=0.5)
    generate(LESSON, "train", 2, plain, progress=False)
    seeds = existing_seeds(folder)
    assert load_episode(os.path.join(folder, f"{seeds[0]:06d}.npz")).variant_lang is None

    every = DemoConfig.defaults(data_dir=root, camera_scale=0.5, every_instruction=True)
    summary = generate(LESSON, "train", 2, every, progress=False)
    assert summary["saved"] == 2 and summary["every_instruction"] is True  # both re-recorded
    assert existing_seeds(folder) == seeds
    for seed in seeds:
        ep = load_episode(os.path.join(folder, f"{seed:06d}.npz"))
        assert ep.meta["every_instruction"] is True
        assert ep.variant_pose0.shape == ep.variant_pose1.shape == (1, 5, 7)
        assert len({ep.lang_goal[0], *ep.variant_lang[0]}) == 6
    assert generate(LESSON, "train", 2, every, progress=False)["skipped_existing"] == 2  # and then kept


def test_every_instruction_on_a_task_without_variants_is_refused(capsys, one_error_line):
    with pytest.raises(SystemExit) as exit_info:
        demos_cli.run_cli(
            lambda: demos_cli.main(
                ["--task", "place-red-in-green", "--n", "1", "--every-instruction", "--data-dir", "x"]
            )
        )
    one_error_line(exit_info.value.code, capsys.readouterr().err, "place-red-in-green", LESSON)
