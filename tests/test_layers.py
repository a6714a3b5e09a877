"""The library's layers depend one way: no module imports a layer above its own (read from the source).

Every import counts: at module level or inside a function, absolute or relative, and modules named by a
string to ``importlib.import_module``, ``__import__`` or ``importlib.resources.files``. A string that names a
module for another library to import later (Gymnasium's entry point ``cliport.gym_env:CliportEnv``) is not an
import of the module that holds it.
"""

from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: The layers, lowest first: each unit (a package, or a module of the top package) and the units it may
#: import. A unit may only name units above it in this table, so the table is an order with no cycle
#: (test_table_has_no_cycle). A unit's own modules may import each other.
LAYERS: dict[str, tuple[str, ...]] = {
    "cliport.errors": (),  # the user-error exceptions
    "cliport.configs": (),  # configs/*.toml (package data)
    "cliport.published": (),  # the papers' published results and the blind ceilings (package data)
    "cliport.gym_registration": (),  # Gymnasium ids of the tasks, by name only (run on import cliport)
    "cliport": ("cliport.gym_registration",),  # the top package's __init__: version, checkout finder
    "cliport.utils": ("cliport.errors", "cliport.configs"),
    "cliport.env": ("cliport.errors", "cliport.utils"),  # the simulator
    "cliport.tasks": ("cliport.errors", "cliport.env"),  # tasks/: the Ravens tasks and their oracles
    "cliport.models.encoders": ("cliport.errors", "cliport.utils"),  # frozen pretrained encoders, their weights
    "cliport.models": ("cliport.errors", "cliport.utils", "cliport.models.encoders"),  # nets and heads
    "cliport.data": ("cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.tasks"),
    "cliport.gym_env": ("cliport.errors", "cliport.env", "cliport.tasks", "cliport.data"),
    "cliport.agents": (
        "cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.models.encoders", "cliport.models",
    ),
    "cliport.train": (
        "cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.tasks", "cliport.models.encoders",
        "cliport.models", "cliport.data", "cliport.agents",
    ),
    "cliport.evaluation": (
        "cliport", "cliport.errors", "cliport.published", "cliport.utils", "cliport.env", "cliport.tasks",
        "cliport.data", "cliport.agents",
    ),
    "cliport.deploy": (
        "cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.tasks", "cliport.data",
        "cliport.agents", "cliport.evaluation",
    ),
    "cliport.pretrain": (
        "cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.tasks", "cliport.models.encoders",
        "cliport.evaluation",
    ),  # contrastive pretraining of the encoders on rendered crops, its probe, the colour-transfer report
    "cliport.study": (
        "cliport.errors", "cliport.utils", "cliport.tasks", "cliport.data", "cliport.agents", "cliport.train",
        "cliport.evaluation",
    ),
    "cliport.cli": (
        "cliport", "cliport.errors", "cliport.utils", "cliport.env", "cliport.tasks", "cliport.data",
        "cliport.agents", "cliport.train", "cliport.evaluation", "cliport.deploy", "cliport.study", "cliport.pretrain",
    ),
}  # fmt: skip

#: Libraries a unit must never import itself: the simulator and its tasks run without torch, and
#: ``import cliport`` (which registers the Gymnasium ids) loads neither torch nor the simulator.
NEVER_IMPORTS = {
    "cliport": ("torch", "pybullet"),
    "cliport.gym_registration": ("torch", "pybullet"),
    "cliport.env": ("torch",),
    "cliport.tasks": ("torch",),
    "cliport.gym_env": ("torch",),
}

#: Where each installed package's files are in the checkout (pyproject.toml's package-dir).
SOURCES = {"cliport": ROOT / "cliport", "cliport.tasks": ROOT / "tasks", "cliport.configs": ROOT / "configs"}
_IMPORTING_CALLS = {"import_module", "__import__", "files"}


def module_files() -> dict[str, pathlib.Path]:
    """Every module of the library by its installed name (``cliport.agents.base``, ``cliport.tasks.base``)."""
    modules = {}
    for package, folder in SOURCES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join([package, *parts])] = path
    return modules


MODULES = module_files()


def unit_of(name: str) -> str | None:
    """The unit of LAYERS that holds module (or module attribute) ``name``: the longest one it lies in; the
    top package's unit holds only its ``__init__`` and what that defines, so a module of it that is in no
    other unit has none (None)."""
    found = [u for u in LAYERS if u != "cliport" and (name == u or name.startswith(u + "."))]
    if found:
        return max(found, key=len)
    return "cliport" if name == "cliport" or (name.startswith("cliport.") and name not in MODULES) else None


def _package_of(module: str, path: pathlib.Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def imports(source: str, package: str) -> list[tuple[int, str, bool]]:
    """(line, absolute module name, whether it is imported from) of every import in ``source``, a module of
    package ``package``. ``from p import x`` gives ``p.x`` when ``x`` is a module of ``p``, else ``p`` and True
    (``x`` is defined in ``p``'s ``__init__``)."""
    found: list[tuple[int, str, bool]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name, False) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            for alias in node.names:
                full = f"{origin}.{alias.name}"
                found.append((node.lineno, full, False) if full in MODULES else (node.lineno, origin, True))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            target = node.args[0].value
            if called in _IMPORTING_CALLS and isinstance(target, str):
                if target.startswith("."):  # import_module(".x", package)
                    target = f"{package}{target}"
                if called != "files" or target.split(".")[0] == "cliport":
                    found.append((node.lineno, target, False))
    return found


def violations(modules: dict[str, pathlib.Path]) -> list[str]:
    """One line per import that breaks LAYERS or NEVER_IMPORTS, or that reads a module's own package's
    ``__init__`` (a package's ``__init__`` only re-exports its modules' names, so importing it from one of
    them goes round in a circle)."""
    bad = []
    for module, path in modules.items():
        unit = unit_of(module)
        assert unit is not None, f"{module} is in no unit of LAYERS"
        package = _package_of(module, path)
        allowed = set(LAYERS[unit]) | {unit}
        where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        for line, name, from_init in imports(path.read_text(), package):
            top = name.split(".")[0]
            if top in NEVER_IMPORTS.get(unit, ()):
                bad.append(f"{where}:{line} imports {name}: {unit} never imports {top}")
            if top != "cliport":
                continue
            target = unit_of(name)
            if target not in allowed:
                bad.append(f"{where}:{line} imports {name}: {unit} may not import {target}")
            if from_init and name == package != "cliport" and path.name != "__init__.py":
                bad.append(f"{where}:{line} imports from its own package's __init__ ({name}): import the module")
    return list(dict.fromkeys(bad))  # one line for ``from p import a, b``


def test_no_upward_imports():
    assert violations(MODULES) == []


def test_table_has_no_cycle():
    """Every unit may only import units listed before it, so following imports only ever goes down."""
    order = list(LAYERS)
    for unit, allowed in LAYERS.items():
        for dep in allowed:
            assert dep in LAYERS, f"{unit} names {dep}, which is not a unit"
            assert order.index(dep) < order.index(unit), f"{unit} may import {dep}, which is not below it"


def test_every_module_is_in_a_unit():
    """A new package or top-level module must be given its place in LAYERS."""
    outside = [m for m in MODULES if unit_of(m) is None]
    assert outside == []
    assert {unit_of(m) for m in MODULES} == set(LAYERS)  # no unit in the table without modules


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("def f():\n    from cliport.deploy.hub import resolve_run_dir\n", "cliport.deploy.hub"),
        ("from ..train import config\n", "cliport.train.config"),
        ("from . import decode\n", "cliport.agents.decode"),
        ("import importlib\nimportlib.import_module('cliport.study')\n", "cliport.study"),
        ("def f():\n    return __import__('cliport.cli.common')\n", "cliport.cli.common"),
        ("from importlib import resources\nresources.files('cliport.published')\n", "cliport.published"),
        ("from cliport import tasks\n", "cliport.tasks"),
        ("from cliport import __version__\n", "cliport"),
    ],
)
def test_every_kind_of_import_is_read(source, expected):
    names = [name for _, name, _ in imports(source, "cliport.agents")]
    assert names and unit_of(names[-1]) == unit_of(expected)


def test_upward_and_own_package_imports_are_caught(tmp_path):
    """Planted in a stand-in for the agents' base module: an upward lazy import, its package's __init__, torch
    in the simulator."""
    base = tmp_path / "base.py"
    base.write_text("def f():\n    from cliport.deploy import hub\n    from cliport.agents import make_agent\n")
    env = tmp_path / "robot.py"
    env.write_text("import torch.nn\n")
    found = violations({"cliport.agents.base": base, "cliport.env.robot": env})
    assert len(found) == 3, found
    assert "base.py:2 imports cliport.deploy.hub: cliport.agents may not import cliport.deploy" in found[0]
    assert "base.py:3 imports from its own package's __init__ (cliport.agents)" in found[1]
    assert "robot.py:1 imports torch.nn: cliport.env never imports torch" in found[2]
