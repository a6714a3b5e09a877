"""One decision of a run's defaults (place rotations, renderer), and what each entry resolves from it: configs
built, nothing trained."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from cliport.cli.train import _parser, config_from_args
from cliport.errors import ConfigError
from cliport.study import StudyConfig
from cliport.train.config import TrainConfig
from cliport.train.run_defaults import run_defaults

ROUND_BOWLS = "put-block-in-bowl-seen-colors"  # nothing checks the place yaw
KITS = "assembling-kits-seq-seen-colors"  # each hole has its yaw
QUICKSTART = Path(__file__).resolve().parents[2] / "scripts" / "quickstart.py"


def test_round_bowls_take_one_rotation_kits_the_agents_and_the_papers_protocol_the_agents_on_both() -> None:
    bowls, kits = run_defaults(ROUND_BOWLS), run_defaults(KITS)
    assert (bowls.n_rotations, kits.n_rotations) == (1, None)  # None: the agent config's count
    assert "one place rotation" in bowls.note and kits.note is None
    papers = run_defaults(ROUND_BOWLS, papers_protocol=True)
    assert papers.n_rotations is None and "keeps the agent's 36 place rotations" in papers.note
    assert run_defaults(KITS, papers_protocol=True).note is None
    assert run_defaults(ROUND_BOWLS, n_rotations=12) == run_defaults(ROUND_BOWLS, n_rotations=12, papers_protocol=True)
    assert run_defaults(ROUND_BOWLS, n_rotations=12).note is None  # given: nothing to say


def test_the_renderer_is_the_given_one_else_the_runs_else_the_workcells() -> None:
    assert run_defaults(KITS).renderer == "auto"  # configs/env.toml
    assert run_defaults(KITS, renderer="cpu").renderer == "cpu"
    with pytest.raises(ConfigError, match="--renderer must be auto, egl or cpu, got 'gpu'"):
        run_defaults(KITS, renderer="gpu")
    saved = _cliport_train("--task", ROUND_BOWLS, "--renderer", "egl")
    assert run_defaults(KITS, saved=saved).renderer == "egl"  # cliport-eval renders as the run did
    assert run_defaults(KITS, renderer="cpu", saved=saved).renderer == "cpu"
    assert run_defaults(KITS, saved=saved).n_rotations == 1  # the run's own count, whatever the task


def _cliport_train(*flags: str) -> TrainConfig:
    parser, dests = _parser()
    return config_from_args(parser.parse_args(["--agent", "two_stream", *flags]), dests)


def _reproduce(task: str, **agent_config: int) -> TrainConfig:
    study = StudyConfig(tasks=[task], agents=["two_stream"], recipes=["cliport"], n_demos=[1], n_steps=4, out="o",
                        data_dir="d", agent_config=agent_config)  # fmt: skip
    return study.train_config("two_stream", 1, task=task)


def _quickstart() -> ModuleType:
    spec = importlib.util.spec_from_file_location("quickstart_run_defaults", QUICKSTART)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _quickstart_config(module: ModuleType, *flags: str) -> TrainConfig:
    args = module.parse_args("cpu", ["--agent", "two_stream", *flags])
    return module.train_config(args, "d", "r", "random", check_saved=False)


def test_what_each_training_entry_resolves_for_round_bowls_and_kits(capsys) -> None:
    quickstart = _quickstart()
    resolved = {
        "cliport-train": [_cliport_train("--task", task) for task in (ROUND_BOWLS, KITS)],
        "cliport-reproduce": [_reproduce(task) for task in (ROUND_BOWLS, KITS)],
        "quickstart": [_quickstart_config(quickstart, "--task", task) for task in (ROUND_BOWLS, KITS)],
    }
    rotations = {entry: [c.agent_config.n_rotations for c in configs] for entry, configs in resolved.items()}
    assert rotations == {"cliport-train": [1, 36], "cliport-reproduce": [36, 36], "quickstart": [1, 36]}
    assert {c.env.renderer for configs in resolved.values() for c in configs} == {"auto"}
    # cliport-train says why it chose one rotation (once, for the round bowls); the study says so in its CLI.
    assert capsys.readouterr().err.count(f"note: the place yaw of {ROUND_BOWLS} carries no information") == 1


def test_a_given_count_wins_everywhere() -> None:
    assert _cliport_train("--task", ROUND_BOWLS, "--agent-option", "n_rotations=12").agent_config.n_rotations == 12
    assert _cliport_train("--task", KITS, "--n-rotations", "4").agent_config.n_rotations == 4
    assert _reproduce(ROUND_BOWLS, n_rotations=1).agent_config.n_rotations == 1
    config = _quickstart_config(_quickstart(), "--task", ROUND_BOWLS, "--n-rotations", "4")
    assert config.agent_config.n_rotations == 4


def test_cliport_reproduce_says_it_keeps_the_papers_rotations_on_round_bowls(monkeypatch, capsys) -> None:
    from cliport.cli import reproduce

    monkeypatch.setattr("cliport.study.run_study", lambda config, **kwargs: {"tasks": []})
    reproduce.main(["--tasks", ROUND_BOWLS, KITS, "--agents", "two_stream", "--out", "o", "--n-demos", "1"])
    err = capsys.readouterr().err
    assert f"note: the place yaw of {ROUND_BOWLS} carries no information" in err
    assert "the papers' protocol keeps the agent's 36 place rotations" in err and KITS not in err
