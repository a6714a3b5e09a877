"""Sharing runs on the Hugging Face Hub, offline: cliport-push --local-dir writes a folder that is a run
folder with a model card; hf://org/name resolves from a pre-filled HF cache; an uncached repo is one line."""

from __future__ import annotations

import os
import shutil
import socket

import numpy as np
import pytest
import torch

from cliport.cli import eval as eval_cli
from cliport.cli import push as push_cli
from cliport.cli.common import run_cli
from cliport.deploy import hub
from cliport.utils.files import read_json, write_json
from cliport.utils.run_dir import RunDir

TASK = "block-insertion"
COMMIT = "0123456789abcdef0123456789abcdef01234567"


@pytest.fixture(autouse=True)
def offline_hub(tmp_path, monkeypatch):
    """HF_HOME in tmp_path, HF_HUB_OFFLINE=1, and no socket may connect anywhere."""
    from huggingface_hub import constants

    home = tmp_path / "hf-home"
    monkeypatch.setenv("HF_HOME", str(home))
    monkeypatch.setenv("HF_HUB_CACHE", str(home / "hub"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setattr(constants, "HF_HOME", str(home))
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(home / "hub"))
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", True)

    def no_network(*args, **kwargs):
        raise AssertionError("a test tried to reach the network")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    return home


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, tiny_config):
    """A tiny run: config.json, checkpoints/step-000002.pt, last.pt (with trainer state), val.json, an eval."""
    from cliport.agents import make_agent
    from cliport.train.config import TrainConfig

    root = str(tmp_path_factory.mktemp("run"))
    run = RunDir(root)
    tiny = tiny_config("transporter_only", n_rotations=4)
    config = TrainConfig.build({"agent": "transporter_only", "task": TASK, "n_demos": 10, "n_steps": 2,
                                "agent_config": tiny, "env": {"camera_scale": 0.5}})  # fmt: skip
    write_json(run.config, config.to_dict())
    torch.manual_seed(0)
    agent = make_agent("transporter_only", config.agent_config)
    agent.save_checkpoint(run.checkpoint(2))
    torch.save({**agent.checkpoint_payload(), "trainer": {"step": 2, "optimizer": {"x": torch.zeros(3)}}},
               run.checkpoint("last"))  # fmt: skip
    write_json(run.val, {"task": TASK, "n_episodes": 2, "checkpoints": {"2": {"mean_score": 37.5, "per_task": [37.5]}},
                         "best_step": 2, "best_score": 37.5})  # fmt: skip
    write_json(os.path.join(run.eval_dir, f"{TASK}-test-2.json"),
               {"task": TASK, "mode": "test", "n_episodes": 4, "mean_score": 41.25, "ci95": [10.0, 72.5],
                "success_rate": 0.25, "success_ci95": [0.05, 0.7], "checkpoint": 2, "episodes": []})  # fmt: skip
    return root


def _push(argv: list[str]) -> None:
    run_cli(lambda: push_cli.main(argv))


@pytest.fixture
def cli_error(capsys, one_error_line):
    """``cli_error(main)``: the one ``error:`` line (exit status 2) that ``run_cli(main)`` ends with."""

    def run(main) -> str:
        capsys.readouterr()
        with pytest.raises(SystemExit) as stop:
            run_cli(main)
        return one_error_line(stop.value.code, capsys.readouterr().err, status=2)

    return run


def _files(folder) -> set[str]:
    return {os.path.relpath(os.path.join(d, f), folder) for d, _, fs in os.walk(folder) for f in fs}


def test_push_local_dir_is_a_run_folder_with_a_model_card(trained_run, tmp_path):
    out = tmp_path / "push"
    _push(["--run-dir", trained_run, "--repo", "org/tiny", "--local-dir", str(out)])
    assert _files(out) == {"README.md", "config.json", "model.safetensors", "val.json", "checkpoints/step-000002.pt",
                           f"eval/{TASK}-test-2.json"}  # fmt: skip
    assert RunDir(str(out)).is_run() and RunDir(str(out)).best_step() == 2
    card = (out / "README.md").read_text()
    assert card.startswith("---\nlibrary_name: cliport\ntags:\n")
    front = card.split("---")[1]
    assert "- transporter_only" in front and f"- {TASK}" in front
    for text in ["| agent | `transporter_only` |", f"| task | `{TASK}` |", "| demos | 10 |", "| steps | 2 |",
                 "| 2 (best) | 37.5 |", f"| {TASK} | test | 2 | 4 | 41.25 (10.0-72.5) | 25% |",
                 "cliport-eval --run-dir hf://org/tiny --mode test", "cliport-predict --run-dir hf://org/tiny",
                 "## Pretrained parts\n\nNone", 'PickPlaceAgent.from_pretrained("hf://org/tiny")',
                 "`model.safetensors` holds the trained weights of checkpoint 2"]:  # fmt: skip
        assert text in card, text


def test_pushed_safetensors_are_the_chosen_checkpoints_weights_without_pickle(trained_run, tmp_path):
    """The run predates safetensors weights (only .pt files): the push writes them from the checkpoint."""
    from safetensors import safe_open
    from safetensors.torch import load_file

    assert not os.path.exists(RunDir(trained_run).model_weights)
    out = tmp_path / "push"
    _push(["--run-dir", trained_run, "--repo", "org/tiny", "--checkpoint", "last", "--local-dir", str(out)])
    weights = load_file(out / "model.safetensors")
    expected = torch.load(RunDir(trained_run).checkpoint("last"), weights_only=True)["state_dict"]
    assert weights.keys() == expected.keys()
    for key, value in expected.items():
        torch.testing.assert_close(weights[key], value, rtol=0, atol=0)
    with safe_open(str(out / "model.safetensors"), framework="pt") as f:
        metadata = f.metadata()
    assert metadata["agent"] == "transporter_only" and metadata["step"] == "2"  # last.pt's trainer step


def test_push_all_strips_training_state(trained_run, tmp_path):
    out = tmp_path / "push"
    _push(["--run-dir", trained_run, "--repo", "org/tiny", "--checkpoint", "all", "--local-dir", str(out)])
    assert {"checkpoints/step-000002.pt", "checkpoints/last.pt"} <= _files(out)
    last = torch.load(out / "checkpoints" / "last.pt", weights_only=True)
    assert "trainer" not in last and {"agent", "config", "state_dict", "weight_sources"} <= set(last)


def test_model_card_lists_weight_sources_not_weights():
    payload = {"weight_sources": {"clip_weights": "openai"}}
    card = hub.model_card({"agent": "two_stream", "task": TASK}, None, [], payload, ["last"], "org/x")
    assert "- `clip_weights`: `openai`" in card and "not included" in card
    assert "No validation results." in card and "Not evaluated yet." in card
    assert "--run-dir hf://org/x --checkpoint last" in card  # no val.json: best cannot be the default
    local = hub.model_card({}, None, [], {"weight_sources": {"clip_weights": "/data/RN50.pt"}}, [1], "org/x")
    assert "a local file, not in this repo: pass `--clip-weights PATH`" in local


def _fill_cache(home, folder, repo_id: str = "org/tiny") -> str:
    """Put ``folder`` into the HF cache layout: hub/models--org--name/snapshots/<commit>/ + refs/main."""
    repo = home / "hub" / ("models--" + repo_id.replace("/", "--"))
    snapshot = repo / "snapshots" / COMMIT
    shutil.copytree(folder, snapshot)
    (repo / "refs").mkdir(parents=True)
    (repo / "refs" / "main").write_text(COMMIT)
    return str(snapshot)


def test_hub_run_resolves_from_the_cache_and_acts_like_the_original(trained_run, tmp_path, offline_hub):
    from cliport.agents import PickPlaceAgent
    from cliport.deploy import Predictor

    out = tmp_path / "push"
    _push(["--run-dir", trained_run, "--repo", "org/tiny", "--local-dir", str(out)])
    snapshot = _fill_cache(offline_hub, out)
    assert hub.resolve_run_dir("hf://org/tiny") == snapshot
    assert hub.resolve_run_dir(f"hf://org/tiny@{COMMIT}") == snapshot
    assert hub.resolve_run_dir(trained_run) == trained_run  # a local folder as before

    predictor = Predictor("hf://org/tiny")  # best from the pushed val.json
    assert predictor.checkpoint_path == RunDir(snapshot).checkpoint(2)
    original = PickPlaceAgent.from_pretrained(RunDir(trained_run).checkpoint(2))
    rng = np.random.default_rng(0)
    obs = {"color": rng.integers(0, 255, (320, 160, 3), dtype=np.uint8),
           "height": rng.uniform(0, 0.1, (320, 160)).astype(np.float32)}  # fmt: skip
    a, b = original.act(obs), predictor.agent.act(obs)
    assert a["pick_pix"] == b["pick_pix"] and a["place_pix"] == b["place_pix"] and a["place_rot"] == b["place_rot"]
    np.testing.assert_array_equal(a["place_heatmap"], b["place_heatmap"])

    from cliport.agents import PickPlaceAgent

    c = PickPlaceAgent.from_pretrained("hf://org/tiny").act(obs)  # model.safetensors of the pushed checkpoint
    assert (a["pick_pix"], a["place_pix"], a["place_bin"]) == (c["pick_pix"], c["place_pix"], c["place_bin"])
    np.testing.assert_array_equal(a["pick_heatmap"], c["pick_heatmap"])
    np.testing.assert_array_equal(a["place_heatmap"], c["place_heatmap"])


def test_uncached_hub_run_is_one_line(cli_error):
    err = cli_error(lambda: eval_cli.main(["--run-dir", "hf://org/missing"]))
    assert "hf://org/missing is not in the local Hugging Face cache" in err
    assert "HF_HUB_OFFLINE" in err and "hf download org/missing" in err and "local run folder" in err
    err = cli_error(lambda: eval_cli.main(["--run-dir", "hf://org/missing@v2"]))
    assert "hf download org/missing --revision v2" in err
    err = cli_error(lambda: eval_cli.main(["--run-dir", "hf://no-slash"]))
    assert "hf://org/name" in err


def test_push_errors_are_one_line(trained_run, tmp_path, monkeypatch, cli_error):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    err = cli_error(lambda: push_cli.main(["--run-dir", trained_run, "--repo", "org/t", "--local-dir",
                                           str(tmp_path / "full")]))  # fmt: skip
    assert "not empty" in err
    err = cli_error(lambda: push_cli.main(["--run-dir", str(tmp_path / "nope"), "--repo", "org/t"]))
    assert "run folder not found" in err

    from huggingface_hub import HfApi

    def refuse(*args, **kwargs):
        raise ConnectionError("no network")

    monkeypatch.setattr(HfApi, "create_repo", refuse)
    err = cli_error(lambda: push_cli.main(["--run-dir", trained_run, "--repo", "org/t"]))
    assert "org/t" in err and "ConnectionError: no network" in err


def test_pushed_val_json_is_unchanged(trained_run, tmp_path):
    out = tmp_path / "push"
    _push(["--run-dir", trained_run, "--repo", "org/tiny", "--checkpoint", "last", "--local-dir", str(out)])
    assert read_json(out / "val.json") == read_json(RunDir(trained_run).val)
    assert "--run-dir hf://org/tiny --checkpoint last" in (out / "README.md").read_text()
