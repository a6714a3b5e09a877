"""``--help`` of every console script answers without importing torch or any agent: the flags come from the config
classes and the registry's table alone (cliport/agents/config.py, cliport/agents/registry.py)."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys
import tomllib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
#: Modules of cliport.agents that --help may import: the package's lazy __init__, the table and the configs.
ALLOWED_AGENT_MODULES = {"cliport.agents", "cliport.agents.registry", "cliport.agents.config"}

# Calls the entry with --help (its output swallowed), then prints the heavy modules it imported.
HELP = """
import contextlib, io, json, sys
sys.argv = [NAME, "--help"]
from MODULE import FUNCTION as entry
code = None
with contextlib.redirect_stdout(io.StringIO()) as out:
    try:
        entry()
    except SystemExit as stop:
        code = stop.code
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "pybullet") or m.startswith("cliport.agents"))
print(json.dumps({"code": code, "usage": out.getvalue().startswith("usage:"), "heavy": heavy}))
"""


def test_every_console_script_is_checked() -> None:
    assert {"cliport-train", "cliport-eval", "cliport-reproduce", "cliport-convert"} <= set(SCRIPTS)


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_help_imports_no_agent_and_no_torch(name: str) -> None:
    module, function = SCRIPTS[name].split(":")
    code = HELP.replace("NAME", repr(name)).replace("MODULE", module).replace("FUNCTION", function)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["code"] == 0 and result["usage"], result
    assert [m for m in result["heavy"] if m not in ALLOWED_AGENT_MODULES] == []


def test_agent_flags_need_no_agent_import() -> None:
    """The registry answers names, config classes and weight fields from its table; a name becomes a class (and
    its module is imported) only when asked."""
    code = (
        "import sys\n"
        "from cliport.agents.registry import _resolve_agent, agent_class, agent_names, config_classes, weight_fields\n"
        "config_class = _resolve_agent('rn50_bert', {'width': 0.5})\n"
        "print(agent_names(), [c.__name__ for c in config_classes()], weight_fields(), config_class.__name__,\n"
        "      'torch' in sys.modules)\n"
        "print(agent_class('rn50_bert').__name__, 'torch' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    first, second = done.stdout.strip().splitlines()
    assert first == (
        "['clip_only', 'rn50_bert', 'transporter_only', 'two_stream'] ['CLIPConfig', 'RN50BERTConfig', "
        "'AgentConfig'] ['clip_weights', 'rn50_weights', 'bert_weights'] RN50BERTConfig False"
    )
    assert second == "RN50BERTAgent True"
