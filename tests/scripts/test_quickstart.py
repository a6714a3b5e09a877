"""scripts/quickstart.py: a tiny run goes through all four phases and resumes; bad settings are one line.
(With its defaults it learns: measured in the README; notebooks/quickstart.ipynb's slow test checks that.)"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "quickstart.py"
TINY = ["--demos", "1", "--steps", "2", "--episodes", "1", "--width", "0.125", "--camera-scale", "0.5"]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=900)


@pytest.mark.e2e
def test_a_tiny_run_goes_through_every_phase_and_resumes(tmp_path, one_error_line):
    out = _run("--out", str(tmp_path), *TINY)
    assert out.returncode == 0, out.stderr
    for phase in ("1/4 demonstrations", "2/4 training transporter_only on cpu", "3/4 evaluating", "4/4 heatmaps"):
        assert phase in out.stdout
    assert "1 place rotation(s)" in out.stdout  # place-red-in-green's bowls are round
    summary = json.loads((tmp_path / "results.json").read_text())
    assert summary["training"]["n_rotations"] == 1 and summary["test"]["n_episodes"] == 1
    assert summary["solved"] in (0, 1) and summary["gif_episode"]["solved"] == bool(summary["solved"])
    assert Path(summary["video"]).is_file() and all(Path(p).is_file() for p in summary["heatmaps"])
    assert f"The agent solved {summary['solved']} of 1 test episodes" in out.stdout

    again = _run("--out", str(tmp_path), *TINY)  # demos and training are kept
    assert again.returncode == 0, again.stderr
    assert json.loads((tmp_path / "results.json").read_text())["demos"]["skipped_existing"] == 1
    assert "train transporter_only" not in again.stderr  # no training progress bar: nothing left to train

    changed = _run("--out", str(tmp_path), *TINY, "--seed", "3")
    one_error_line(
        changed.returncode, changed.stderr, "holds a quickstart run with other settings (seed)", "--out", status=2
    )


def test_bad_settings_are_one_line(tmp_path, one_error_line):
    out = _run("--out", str(tmp_path), "--steps", "0")  # the script's own exit: one line, status 2
    one_error_line(out.returncode, out.stderr, "--steps must be at least 1, got 0", status=2)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--task", "nope"], "unknown task 'nope'"),
        (["--language", "--minutes", "-1"], "--minutes must be at least 0, got -1.0"),
        (["--language", "--check-start", "-1"], "--check-start must be at least 0, got -1"),
        (["--language", "--lr-cooldown", "2"], "--lr-cooldown is a fraction of the training, from 0 to 1, got 2.0"),
    ],
)
def test_bad_settings_are_refused_before_anything_runs(flags, message):
    from cliport.errors import UserError

    with pytest.raises(UserError) as raised:
        _quickstart_module().parse_args("cpu", flags)
    assert message in str(raised.value)


@pytest.mark.e2e
def test_the_language_lesson_measures_instruction_following_and_draws_two_instructions(tmp_path):
    out = _run("--language", "--out", str(tmp_path), "--demos", "1", "--steps", "2", "--episodes", "1",
               "--swap-scenes", "1", "--clip-weights", "random", "--check-scenes", "2")  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "2/4 training two_stream on cpu" in out.stdout and "CLIP weights random" in out.stdout
    summary = json.loads((tmp_path / "results.json").read_text())
    assert summary["agent"] == "two_stream" and summary["task"] == "put-one-block-in-bowl-seen-colors"
    assert summary["training"]["clip_weights"] == "random" and summary["training"]["map_scale"] == 0.5
    assert summary["training"]["every_instruction"] and summary["training"]["center_sentences"]
    assert summary["training"]["pair_contrasts"] and isinstance(summary["training"]["init_draws"], dict)
    assert "every instruction of each scene" in out.stdout and "centred sentence features" in out.stdout
    assert "contrasting pairs" in out.stdout
    following = summary["instruction_following"]
    assert following["n"] == 2 and following["rate"] == following["followed"] / 2  # two other blocks per scene
    figure = summary["two_instructions"]
    assert Path(figure["path"]).is_file() and len(set(figure["instructions"])) == 2
    assert f"Instruction following: {following['followed']} of 2 swapped instructions" in out.stdout
    assert "random here" in out.stdout
    # The first line: the probe's step time and what it means for the time budget.
    first = out.stdout.splitlines()[0]
    assert first.startswith("machine: ") and "a training step takes" in first and "10.5-minute training budget" in first
    assert summary["machine"]["probe_step_s"] > 0
    # 2 steps (the cap under the budget): checked at the last step on held-out validation scenes, that step tested.
    training = summary["training"]
    assert training["steps"] == 2 and training["tested_step"] == 2 and training["trained_s"] > 0
    assert [row["step"] for row in training["held_out"]["curve"]] == [2]
    assert training["held_out"]["check"]["samples"] == 12  # 2 validation scenes x 6 instructions
    assert training["held_out"]["check"]["start"] == 450 and training["lr_cooldown"] == 0.5
    assert training["batch_size"] == 2  # the CPU lesson's: each batch a contrasting pair
    assert not summary["aims"]["met"] and "The lesson's aims" in out.stdout and "not met: solved" in out.stdout


def test_the_aims_verdict_names_what_was_missed():
    verdict = _quickstart_module().aims_verdict
    aims = {"solved": 0.8, "followed": 0.9, "minutes": 15}
    met = verdict(aims, {"success_rate": 0.85}, {"rate": 0.95}, 14 * 60)
    assert met["met"] and met["line"].endswith("met.")
    missed = verdict(aims, {"success_rate": 0.6}, {"rate": 0.95}, 16 * 60)
    assert not missed["met"]
    assert missed["line"].endswith("not met: solved 60 % (aim 80 %); 16.0 minutes (aim 15).")


def _quickstart_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("quickstart_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_flag_named_as_a_config_field_is_made_from_the_field(monkeypatch):
    """A flag with the name of a train, workcell or agent config field comes from the shared flag builder (its help
    the field's description unless the quickstart's use differs), with configs/quickstart.toml's default."""
    import dataclasses

    from cliport.agents.registry import config_classes
    from cliport.env.config import EnvConfig
    from cliport.train.config import TrainConfig
    from cliport.utils.config import device_defaults

    quickstart = _quickstart_module()
    add_flags, built = quickstart.add_flags, []

    def recording(*args, **kwargs):
        dests = add_flags(*args, **kwargs)
        built.extend(dests)
        return dests

    monkeypatch.setattr(quickstart, "add_flags", recording)
    setting = device_defaults("quickstart", "cpu")
    parser, _ = quickstart.build_parser(setting, language=False)
    fields = {f.name for cls in (TrainConfig, EnvConfig, *config_classes()) for f in dataclasses.fields(cls)}
    named_as_fields = {action.dest for action in parser._actions if action.dest in fields}
    assert named_as_fields == {*quickstart.RUN_FLAGS, *quickstart.LESSON_AGENT_FLAGS, "camera_scale"}
    assert named_as_fields <= set(built)
    args = parser.parse_args([])
    assert (args.task, args.agent, args.width, args.camera_scale) == tuple(
        setting[k] for k in ("task", "agent", "width", "camera_scale")
    )


@pytest.mark.parametrize("available", [True, False])
def test_auto_clip_weights_are_the_published_ones_where_they_can_be_had(available, monkeypatch, capsys):
    import argparse

    from cliport.models.encoders import clip_weights

    quickstart = _quickstart_module()
    monkeypatch.setattr(clip_weights, "published_weights_available", lambda *a, **k: available)
    args = argparse.Namespace(agent="two_stream", clip_weights="auto")
    assert quickstart.resolve_clip_weights(args) == ("openai" if available else "random")
    assert ("RANDOM CLIP weights" in capsys.readouterr().err) == (not available)
    assert quickstart.resolve_clip_weights(argparse.Namespace(agent="two_stream", clip_weights="/w.pt")) == "/w.pt"
    assert quickstart.resolve_clip_weights(argparse.Namespace(agent="transporter_only", clip_weights="auto")) is None


@pytest.mark.parametrize(
    "flags, pairs",
    [([], True), (["--no-pair-contrasts"], False), (["--no-every-instruction"], False)],
)
def test_the_lesson_pairs_contrasts_where_it_has_every_instruction(flags, pairs, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["quickstart.py", "--language", *flags])
    args = _quickstart_module().parse_args("cpu")
    assert args.pair_contrasts is pairs


def test_the_cpu_lesson_trains_pairs_in_one_batch_cools_its_rate_down_and_checks_ten_scenes(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["quickstart.py", "--language"])
    quickstart = _quickstart_module()
    cpu = quickstart.parse_args("cpu")
    assert (cpu.batch_size, cpu.lr, cpu.lr_cooldown, cpu.check_scenes, cpu.check_every, cpu.check_start) == (
        2,
        8e-4,
        0.5,
        10,
        150,
        450,
    )
    assert cpu.scale_up_mid  # the up-blocks narrowed with the width: half the arithmetic of a step
    cuda = quickstart.parse_args("cuda")  # the GPU lesson's measured settings: batch 1, a constant rate
    assert (cuda.batch_size, cuda.lr, cuda.lr_cooldown, cuda.check_every, cuda.check_start) == (1, 2e-4, 0.0, 300, 900)
    assert not cuda.scale_up_mid  # the published width: the reference's net either way
    monkeypatch.setattr(sys, "argv", ["quickstart.py", "--language", "--batch-size", "1", "--check-start", "900"])
    assert (quickstart.parse_args("cpu").batch_size, quickstart.parse_args("cpu").check_start) == (1, 900)
    monkeypatch.setattr(sys, "argv", ["quickstart.py"])
    plain = quickstart.parse_args("cpu")  # the transporter_only quickstart: unchanged
    assert (plain.batch_size, plain.lr_cooldown) == (1, 0.0)


def test_a_budget_under_the_measured_steps_says_which_minutes_train_them(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["quickstart.py", "--language"])
    quickstart = _quickstart_module()
    assert quickstart.parse_args("cpu").measured_steps == 1000 and quickstart.parse_args("cuda").measured_steps == 0
    # 1.07 s a step (a 2-core EPYC of family 25): 588 steps in 10.5 minutes; 700 at 1.07 s plus 5 % is 13.1 minutes.
    steps, means = quickstart.budget_means(1.07, 10.5, 4000, 700)
    assert steps == 588 and "fewer than the 700" in means and "--minutes 13.5 " in means
    steps, means = quickstart.budget_means(0.45, 10.5, 4000, 700)  # a faster CPU: 1400 steps, no advice
    assert steps == 1400 and "--minutes" not in means and "slower machine" in means
    assert quickstart.budget_means(0.01, 10.5, 4000, 700)[0] == 4000  # capped at --steps
    assert "--minutes" not in quickstart.budget_means(1.07, 10.5, 2, 700)[1]  # --steps, not the budget, holds it
    assert "--minutes" not in quickstart.budget_means(1.07, 10.5, 600, 700)[1]  # --steps under 700: asked for
