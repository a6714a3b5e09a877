"""One decision of the place rotations a run trains with, and what each training entry resolves from it."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import pytest

from cliport.cli.train import _parser, config_from_args
from cliport.study import StudyConfig
from cliport.train.config import default_place_rotations

ROUND_BOWLS = "put-block-in-bowl-seen-colors"  # nothing checks the place yaw
KITS = "assembling-kits"  # each hole has its yaw
QUICKSTART = Path(__file__).resolve().parents[2] / "scripts" / "quickstart.py"


def test_round_bowls_take_one_rotation_and_kits_the_agents() -> None:
    assert default_place_rotations(ROUND_BOWLS) == 1
    assert default_place_rotations(KITS) is None


def _train(*flags: str) -> int:
    parser, dests = _parser()
    return config_from_args(parser.parse_args(["--agent", "transporter_only", *flags]), dests).agent_config.n_rotations


def test_cliport_train_resolves_one_rotation_for_round_bowls_36_for_kits_and_a_given_count_always() -> None:
    assert _train("--task", ROUND_BOWLS) == 1
    assert _train("--task", KITS) == 36
    assert _train("--task", ROUND_BOWLS, "--agent-option", "n_rotations=12") == 12


def test_the_quickstart_resolves_as_cliport_train() -> None:
    spec = importlib.util.spec_from_file_location("quickstart_rotations", QUICKSTART)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def resolved(task: str, given: int | None = None) -> int:
        return module.place_rotations(argparse.Namespace(task=task, agent="two_stream", n_rotations=given))

    assert (resolved(ROUND_BOWLS), resolved(KITS), resolved(ROUND_BOWLS, 4)) == (1, 36, 4)


@pytest.mark.parametrize("task", [ROUND_BOWLS, KITS])
def test_the_study_keeps_the_papers_36_on_every_task(task: str, tmp_path: Path) -> None:
    study = StudyConfig(tasks=[task], agents=["transporter_only"], recipes=["ravens"], n_demos=[1], n_steps=4,
                        out=str(tmp_path), data_dir="d")  # fmt: skip
    assert study.train_config("transporter_only", 1, task=task).agent_config.n_rotations == 36
