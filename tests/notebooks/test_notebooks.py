"""Every notebook runs top to bottom with its tiny default parameters (its code cells, in order)."""

import glob
import json
import os

import matplotlib
import pytest

NOTEBOOKS = sorted(glob.glob(os.path.join(os.path.dirname(__file__), "..", "..", "notebooks", "*.ipynb")))


def test_notebooks_exist():
    names = {os.path.basename(p) for p in NOTEBOOKS}
    assert {"quickstart.ipynb", "affordances.ipynb", "dataset_explorer.ipynb", "reproduction_study.ipynb"} <= names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=os.path.basename)
def test_notebook_runs(path, monkeypatch, tmp_path):
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(plt, "show", lambda *a, **k: plt.close("all"))
    with open(path) as f:
        notebook = json.load(f)
    assert all(not c.get("outputs") for c in notebook["cells"] if c["cell_type"] == "code"), "outputs are committed"
    namespace: dict = {"__name__": "__notebook__"}
    for i, cell in enumerate(c for c in notebook["cells"] if c["cell_type"] == "code"):
        source = "".join(cell["source"])
        if i == 0:
            assert "FULL_SIZE = False" in source, "the first code cell must be the parameter cell"
        exec(compile(source, f"{os.path.basename(path)}[cell {i}]", "exec"), namespace)
