"""The library's layers depend one way: no module imports a layer above its own (read from the source)."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

# package -> cliport packages it must never import (at module level or inside functions)
FORBIDDEN = {
    "env": ["torch", "cliport.models", "cliport.agents", "cliport.data", "cliport.train", "cliport.evaluation",
            "cliport.deploy"],
    "utils": ["cliport.env", "cliport.models", "cliport.agents", "cliport.data", "cliport.train",
              "cliport.evaluation", "cliport.cli", "cliport.study", "cliport.deploy"],
    "models": ["cliport.agents", "cliport.data", "cliport.train", "cliport.evaluation", "cliport.cli"],
    "agents": ["cliport.data", "cliport.train", "cliport.evaluation", "cliport.cli", "cliport.study"],
    "data": ["cliport.agents", "cliport.models", "cliport.train", "cliport.evaluation", "cliport.cli",
             "cliport.deploy"],
    "train": ["cliport.evaluation", "cliport.cli", "cliport.study"],
    "evaluation": ["cliport.train", "cliport.cli", "cliport.study", "cliport.deploy"],
    "deploy": ["cliport.train", "cliport.cli", "cliport.study"],
}  # fmt: skip


def _imports(path: pathlib.Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_upward_imports(package):
    bad = []
    for path in sorted((ROOT / "cliport" / package).glob("*.py")):
        for name in _imports(path):
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[package]):
                bad.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not bad, bad
