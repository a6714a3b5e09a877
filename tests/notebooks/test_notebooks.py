"""Every notebook runs top to bottom with its tiny default parameters (its code cells, in order); the
affordances notebook takes a converted reference checkpoint; the quickstart notebook learns with its own
defaults (slow)."""

import glob
import json
import os
import tempfile

import matplotlib
import pytest
import torch

from cliport.env.assets import PREFIX as ASSETS_PREFIX

pytestmark = [pytest.mark.e2e]


@pytest.fixture(autouse=True)
def notebook_folders_in_tmp_path(monkeypatch, tmp_path):
    """The notebooks' work folders (``tempfile.mkdtemp(prefix="cliport-<notebook>-")``, which a user keeps: hundreds of
    MB each) go under ``tmp_path``, so that a passing test leaves nothing on the disk. Every other temporary folder
    stays where it was: multiprocessing's sockets need a short path, and the process's asset folder
    (``cliport.env.assets``) outlives a test."""
    mkdtemp = tempfile.mkdtemp

    def in_tmp_path(suffix=None, prefix=None, dir=None):
        if dir is None and prefix and prefix.startswith("cliport-") and not prefix.startswith(ASSETS_PREFIX):
            dir = str(tmp_path)
        return mkdtemp(suffix, prefix, dir)

    monkeypatch.setattr(tempfile, "mkdtemp", in_tmp_path)


NOTEBOOKS = sorted(glob.glob(os.path.join(os.path.dirname(__file__), "..", "..", "notebooks", "*.ipynb")))


def run_notebook(name: str, **parameters) -> dict:
    """Execute the code cells of ``notebooks/<name>`` in order, setting ``parameters`` after its parameter
    cell (the first code cell); returns the namespace."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = next(p for p in NOTEBOOKS if os.path.basename(p) == name)
    with open(path) as f:
        notebook = json.load(f)
    assert all(not c.get("outputs") for c in notebook["cells"] if c["cell_type"] == "code"), "outputs are committed"
    namespace: dict = {"__name__": "__notebook__"}
    show = plt.show
    plt.show = lambda *a, **k: plt.close("all")
    try:
        for i, cell in enumerate(c for c in notebook["cells"] if c["cell_type"] == "code"):
            source = "".join(cell["source"])
            exec(compile(source, f"{name}[cell {i}]", "exec"), namespace)
            if i == 0:
                assert "FULL_SIZE = False" in source, "the first code cell must be the parameter cell"
                unknown = set(parameters) - set(namespace)
                assert not unknown, f"{name} has no parameters {unknown}"
                namespace.update(parameters)
    finally:
        plt.show = show
    return namespace


def test_notebooks_exist():
    names = {os.path.basename(p) for p in NOTEBOOKS}
    assert {
        "quickstart.ipynb", "language.ipynb", "affordances.ipynb", "dataset_explorer.ipynb", "reproduction_study.ipynb",
        "pretraining.ipynb",
    } <= names  # fmt: skip


@pytest.mark.parametrize("name", [os.path.basename(p) for p in NOTEBOOKS])
def test_notebook_runs(name, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    smoke = name in ("quickstart.ipynb", "language.ipynb", "pretraining.ipynb")
    run_notebook(name, **({"SMOKE": True} if smoke else {}))


def test_affordances_notebook_takes_a_converted_checkpoint(monkeypatch, tmp_path):
    """A checkpoint in the reference's Lightning format, converted by cliport-convert, is what the notebook
    shows: its heatmaps are the converted agent's."""
    from cliport.agents import make_agent
    from cliport.models import reference_names
    from cliport.train.convert import convert_checkpoint

    monkeypatch.chdir(tmp_path)
    torch.manual_seed(0)
    agent = make_agent("transporter_only", {})
    folder = tmp_path / "place-red-in-green-transporter-n10-train" / "checkpoints"
    folder.mkdir(parents=True)
    ckpt = folder / "steps=2000-val_loss=0.00000000.ckpt"
    state = reference_names.to_reference("transporter_only", agent.trainable_state_dict())
    torch.save({"epoch": 1, "global_step": 2000, "state_dict": state}, ckpt)
    convert_checkpoint(str(ckpt), str(tmp_path / "run"))
    namespace = run_notebook("affordances.ipynb", CHECKPOINT=str(tmp_path / "run" / "checkpoints" / "last.pt"))
    assert namespace["agent"].name == "transporter_only"
    obs, text = namespace["obs"], namespace["INSTRUCTIONS"][-1]
    assert namespace["act"]["pick_pix"] == agent.act(obs, text)["pick_pix"]


@pytest.mark.slow
def test_quickstart_notebook_learns(monkeypatch, tmp_path):
    """With its default parameters (the CPU quickstart's settings) the notebook trains an agent that solves
    most of its 20 test episodes and shows one it solved (about 4 minutes on 2 cores)."""
    monkeypatch.chdir(tmp_path)
    namespace = run_notebook("quickstart.ipynb")
    assert namespace["result"]["n_episodes"] == 20
    assert namespace["result"]["success_rate"] >= 0.8, namespace["result"]["success_rate"]
    assert namespace["rollout"]["task_reward"] > 0.99


@pytest.mark.slow
def test_language_notebook_learns(monkeypatch, tmp_path):
    """With its default parameters (the CPU language lesson's settings) the notebook trains a two-stream agent
    that solves most of its 20 test episodes and picks the block a swapped instruction names."""
    monkeypatch.chdir(tmp_path)
    namespace = run_notebook("language.ipynb")
    assert namespace["result"]["n_episodes"] == 20
    assert namespace["result"]["success_rate"] >= 0.8, namespace["result"]["success_rate"]
    assert namespace["following"]["n"] >= 20 and namespace["following"]["rate"] >= 0.9, namespace["following"]
