"""End to end on CPU: demos -> cliport-train (both agents, 10 steps) -> cliport-eval, plus bad input."""

import json
import os

import pytest

from cliport.agents.registry import AGENTS
from cliport.cli import demos as demos_cli
from cliport.cli import eval as eval_cli
from cliport.cli import train as train_cli
from cliport.cli.common import run_cli
from cliport.env.environment import expected_renderer
from cliport.train import step_loop
from cliport.utils.files import load_torch
from cliport.utils.run_dir import RunDir

pytestmark = [pytest.mark.e2e]

TASK = "block-insertion"
TINY = ["--width", "0.125", "--agent-option", "n_rotations=4", "--agent-option", "crop_size=32"]


def _run(main, argv):
    run_cli(lambda: main(argv))


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    root = str(tmp_path_factory.mktemp("e2e"))
    _run(demos_cli.main, ["--task", TASK, "--n", "2", "--data-dir", root, "--camera-scale", "0.5", "--no-progress"])
    return root


def _train_args(data_dir, run_dir, agent, steps=10, extra=()):
    clip = []
    if "clip_weights" in AGENTS[agent].weight_sources:  # the tiny CLIP: a frozen RN50 is most of a tiny step
        clip = ["--clip-weights", "random", "--semantic-encoder", "cliport-RN-tiny"]
    return [
        "--agent", agent, "--task", TASK, "--n-demos", "2", "--n-steps", str(steps), "--batch-size", "2",
        "--data-dir", data_dir, "--run-dir", run_dir, "--num-workers", "0", "--val-episodes", "1",
        "--camera-scale", "0.5", "--checkpoint-steps", "5", "--checkpoint-every", "0", "--log-every", "5",
        "--no-progress", *clip, *TINY, *extra,
    ]  # fmt: skip


@pytest.fixture(scope="module")
def runs(data_dir, tmp_path_factory):
    """One 10-step run of each agent, validated on 1 episode per checkpoint (shared by the tests)."""
    root = tmp_path_factory.mktemp("runs")
    out = {}
    for agent, recipe in (("transporter_only", "ravens"), ("two_stream", "cliport")):
        out[agent] = str(root / agent)
        _run(train_cli.main, _train_args(data_dir, out[agent], agent, extra=["--recipe", recipe]))
    return out


@pytest.mark.parametrize("agent", ["transporter_only", "two_stream"])
def test_train_then_eval(runs, agent, capsys):
    run_dir = runs[agent]
    assert RunDir(run_dir).checkpoint_steps() == [5, 10]
    recipe = {"transporter_only": "ravens", "two_stream": "cliport"}[agent]
    with open(os.path.join(run_dir, "config.json")) as f:
        saved = json.load(f)
    assert saved["agent"] == agent and saved["recipe"] == recipe
    assert load_torch(RunDir(run_dir).checkpoint(5))["recipe"] == recipe
    if agent == "two_stream":  # CLIP's batch norms trained: each net's running statistics moved
        assert saved["agent_config"]["per_net_clip_stats"] is True
        state = load_torch(RunDir(run_dir).checkpoint(10))["state_dict"]
        assert any("encoder_stats" in k for k in state)
    with open(os.path.join(run_dir, "val.json")) as f:
        val = json.load(f)
    assert set(val["checkpoints"]) == {"5", "10"} and val["best_step"] in (5, 10)
    assert val["renderer"] == expected_renderer("auto")  # the record of what validation rendered with
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        assert [line.split(",")[0] for line in f.read().split()[1:]] == ["5", "10"]
    capsys.readouterr()
    _run(eval_cli.main, ["--run-dir", run_dir, "--n-episodes", "2", "--camera-scale", "0.5", "--no-progress"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["n_episodes"] == 2 and summary["agent"] == agent and summary["mode"] == "test"
    assert 0.0 <= summary["mean_score"] <= 100.0 and len(summary["ci95"]) == 2 and len(summary["success_ci95"]) == 2
    assert summary["clip_weights"] == ("random" if agent == "two_stream" else None)
    assert summary["checkpoint"] == val["best_step"] and summary["renderer"] == val["renderer"]
    assert summary["recipe"] == recipe
    assert summary["environment"]["cpu_line"] and summary["environment"]["command"]  # where it was measured
    with open(os.path.join(run_dir, "eval", f"{TASK}-test-{val['best_step']}.json")) as f:
        assert [e["seed"] for e in json.load(f)["episodes"]] == [10001, 10003]


def test_resume_after_interruption(data_dir, tmp_path, monkeypatch, capsys):
    run_dir = str(tmp_path / "resume")
    real = step_loop._batches

    def interrupted(loader):
        for i, batch in enumerate(real(loader)):
            if i == 7:
                raise KeyboardInterrupt
            yield batch

    monkeypatch.setattr(step_loop, "_batches", interrupted)
    with pytest.raises(SystemExit) as stop:
        _run(train_cli.main, _train_args(data_dir, run_dir, "transporter_only", extra=["--val-episodes", "0"]))
    assert stop.value.code == 130
    monkeypatch.setattr(step_loop, "_batches", real)
    assert load_torch(RunDir(run_dir).checkpoint("last"))["trainer"]["step"] == 7
    with pytest.raises(SystemExit) as stop:  # a run keeps its recipe
        _run(train_cli.main, ["--run-dir", run_dir, "--resume", "--recipe", "cliport", "--no-progress"])
    assert stop.value.code == 2
    assert "trains with the ravens recipe, not cliport" in capsys.readouterr().err
    _run(train_cli.main, ["--run-dir", run_dir, "--resume", "--no-progress"])
    assert load_torch(RunDir(run_dir).checkpoint("last"))["trainer"]["step"] == 10
    assert RunDir(run_dir).checkpoint_steps() == [5, 10]
    with pytest.raises(SystemExit) as stop:  # trained without validation: no "best" to pick
        _run(eval_cli.main, ["--run-dir", run_dir, "--checkpoint", "best"])
    assert stop.value.code == 2


@pytest.mark.parametrize(
    "main, args, message",
    [
        (train_cli.main, ["--agent", "cliport9", "--task", TASK], "unknown agent 'cliport9'"),
        (
            train_cli.main,
            ["--agent", "transporter_only", "--task", "block-insertoin"],
            "unknown task 'block-insertoin'",
        ),
        (
            train_cli.main,
            ["--agent", "transporter_only", "--task", TASK, "--data-dir", "/nonexistent"],
            "no demonstrations",
        ),
        (
            train_cli.main,
            ["--agent", "transporter_only", "--task", TASK, "--n-demos", "50"],
            "has 2 episodes but n_demos=50",
        ),
        (eval_cli.main, ["--run-dir", "/nonexistent"], "run folder not found"),
    ],
)
def test_bad_input_is_one_clear_line(data_dir, tmp_path, capsys, one_error_line, main, args, message):
    if main is train_cli.main and "--data-dir" not in args:
        args += ["--data-dir", data_dir]
    args += ["--run-dir", str(tmp_path / "bad")] if main is train_cli.main else []
    with pytest.raises(SystemExit) as stop:
        _run(main, args)
    one_error_line(stop.value.code, capsys.readouterr().err, message, status=2)


def test_eval_rejects_other_agent_and_empty_lang(runs, capsys, one_error_line):
    run_dir = runs["transporter_only"]
    for args, message in [
        (
            ["--agent", "two_stream", "--checkpoint", "last"],
            "is a checkpoint of agent 'transporter_only', not 'two_stream'",
        ),
        (["--lang", "  "], "--lang must be a non-empty instruction"),
        (["--checkpoint", "7"], "--checkpoint must be best, last, all or one of the saved steps [5, 10]"),
    ]:
        capsys.readouterr()
        with pytest.raises(SystemExit) as stop:
            _run(eval_cli.main, ["--run-dir", run_dir, *args])
        one_error_line(stop.value.code, capsys.readouterr().err, message, status=2)
    with pytest.raises(SystemExit):
        _run(train_cli.main, ["--run-dir", run_dir, "--resume", "--agent", "two_stream"])
    assert "is a run of agent 'transporter_only'" in capsys.readouterr().err


def test_free_form_instruction_writes_video_and_heatmaps(runs, tmp_path, capsys):
    capsys.readouterr()
    out = str(tmp_path / "out")
    lang = "put the block in the fixture"
    args = ["--run-dir", runs["two_stream"], "--checkpoint", "last", "--lang", lang, "--seed", "3", "--out", out]
    _run(eval_cli.main, [*args, "--camera-scale", "0.5"])
    result = json.loads(capsys.readouterr().out)
    assert result["instruction"] == "put the block in the fixture" and result["seed"] == 3
    assert os.path.getsize(result["video"]) > 1000 and result["video"].endswith(".gif")
    assert len(result["heatmaps"]) == result["actions"] >= 1
    assert all(os.path.getsize(p) > 1000 for p in result["heatmaps"])
    other = "move the block " + "very " * 80 + "carefully"  # a second instruction on the same seed, too long
    _run(eval_cli.main, [*args[:5], other, *args[6:], "--camera-scale", "0.5"])
    captured = capsys.readouterr()
    second = json.loads(captured.out)
    assert second["video"] != result["video"] and not set(second["heatmaps"]) & set(result["heatmaps"])
    assert os.path.exists(result["video"]) and "CLIP reads the first 24" in captured.err  # the tiny CLIP's context


def test_a_run_that_died_before_its_first_save_starts_again(data_dir, tmp_path, capsys):
    from cliport.train.config import TrainConfig
    from cliport.utils.files import write_json

    run_dir = str(tmp_path / "died")
    args = _train_args(data_dir, run_dir, "transporter_only", steps=2, extra=["--val-episodes", "0"])
    config = TrainConfig.build({"agent": "transporter_only", "task": TASK, "run_dir": run_dir})
    write_json(RunDir(run_dir).config, config.to_dict())  # what a run killed before its first save leaves
    _run(train_cli.main, args)
    assert RunDir(run_dir).checkpoint_steps() == [2]
    with pytest.raises(SystemExit) as stop:  # now it holds progress: a plain re-run must not overwrite it
        _run(train_cli.main, args)
    assert stop.value.code == 2 and "pass --resume" in capsys.readouterr().err


def test_offline_default_clip_weights_fail_in_one_line(data_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "empty-hf-home"))
    args = _train_args(data_dir, str(tmp_path / "offline"), "two_stream")
    args[args.index("--clip-weights") + 1] = "openai"
    with pytest.raises(SystemExit) as stop:
        _run(train_cli.main, args)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.startswith("error: Cannot load CLIP weights 'openai'")
    assert "Traceback" not in err


def test_truncated_checkpoint_is_one_line(runs, tmp_path, capsys, one_error_line):
    import shutil

    run_dir = str(tmp_path / "copy")
    shutil.copytree(runs["transporter_only"], run_dir)
    path = RunDir(run_dir).checkpoint(5)
    with open(path, "r+b") as f:
        f.truncate(os.path.getsize(path) // 3)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        _run(eval_cli.main, ["--run-dir", run_dir, "--checkpoint", "5", "--n-episodes", "1"])
    err = one_error_line(stop.value.code, capsys.readouterr().err, "step-000005.pt", status=2)
    assert "weights_only" not in err


def test_bad_widths_are_rejected(data_dir, tmp_path, capsys):
    for width in ("0", "-1"):
        with pytest.raises(SystemExit) as stop:
            _run(train_cli.main, _train_args(data_dir, str(tmp_path / f"w{width}"), "transporter_only",
                                             extra=["--width", width]))  # fmt: skip
        err = capsys.readouterr().err.strip().splitlines()
        assert stop.value.code == 2 and err == [f"error: width must be > 0, got {float(width)}"]


def test_a_setting_the_agent_lacks_is_one_error_line(data_dir, tmp_path, capsys):
    """An agent flag of another agent (every agent's flags are cliport-train's) is named with the agent's own."""
    args = _train_args(data_dir, str(tmp_path / "run"), "transporter_only", extra=["--clip-weights", "random"])
    with pytest.raises(SystemExit) as stop:
        _run(train_cli.main, args)
    assert stop.value.code == 2 and capsys.readouterr().err.strip().splitlines() == [
        "error: agent transporter_only has no setting(s) clip_weights; "
        "its settings: crop_size, lr, map_scale, n_rotations, width"
    ]
    assert not os.path.exists(tmp_path / "run")


def test_demos_and_validation_must_render_alike(data_dir, tmp_path, capsys):
    """The demos record their renderer; validation with the other one is refused, like another camera scale."""
    from cliport.data.episode_io import existing_seeds, read_meta

    folder = os.path.join(data_dir, f"{TASK}-train")
    demos = read_meta(os.path.join(folder, f"{existing_seeds(folder)[0]:06d}.npz"))["renderer"]
    assert demos == expected_renderer("auto")
    other, setting, fix = ("egl", "egl", "cpu") if demos == "tiny" else ("tiny", "cpu", "egl")
    args = _train_args(data_dir, str(tmp_path / "run"), "transporter_only", extra=["--renderer", setting])
    with pytest.raises(SystemExit) as stop:
        _run(train_cli.main, args)
    err = capsys.readouterr().err.strip().splitlines()[-1:]
    assert stop.value.code == 2 and err == [
        f"error: the {TASK} demos were rendered with {demos} but validation would render with {other} "
        f"(renderer {setting!r} on this machine): pass --renderer {fix}"
    ], err


def test_eval_notes_a_renderer_other_than_validations(runs, tmp_path, capsys):
    import shutil

    from cliport.utils.files import read_json, write_json

    run_dir = str(tmp_path / "copy")
    shutil.copytree(runs["transporter_only"], run_dir)
    val = read_json(RunDir(run_dir).val)
    ours = val["renderer"]
    val["renderer"] = "egl" if ours == "tiny" else "tiny"  # as if validated on another machine
    write_json(RunDir(run_dir).val, val)
    capsys.readouterr()
    _run(eval_cli.main, ["--run-dir", run_dir, "--n-episodes", "1", "--camera-scale", "0.5", "--no-progress"])
    captured = capsys.readouterr()
    assert json.loads(captured.out.strip().splitlines()[-1])["renderer"] == ours
    notes = [line for line in captured.err.splitlines() if line.startswith("note: rendered with")]
    assert notes == [
        f"note: rendered with {ours}; the run was validated with {val['renderer']} (their pixels differ; "
        f"--renderer {'egl' if ours == 'tiny' else 'cpu'} renders as validation did)"
    ], captured.err
