"""mypy over the library as it is installed: ``cliport/`` as ``cliport``, ``tasks/`` as ``cliport.tasks``.

pyproject.toml's package-dir installs the root folder ``tasks/`` as ``cliport.tasks``, a mapping mypy's command
line cannot express (it names a module after its folder, so ``tasks/base.py`` would be ``tasks.base`` and every
``from cliport.tasks ...`` would find nothing). This passes mypy each file with its installed module name and
otherwise runs it as ``mypy`` does: settings from pyproject.toml's ``[tool.mypy]``, the cache in .mypy_cache,
one line per error, exit status 1 when there is any. Usage: ``.venv/bin/python .ci/typecheck.py``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from mypy import build
from mypy.config_parser import parse_config_file
from mypy.errors import CompileError
from mypy.modulefinder import BuildSource
from mypy.options import Options

ROOT = Path(__file__).resolve().parents[1]
#: Installed package name -> its folder in the checkout (pyproject.toml's [tool.setuptools] package-dir).
PACKAGES = {"cliport": ROOT / "cliport", "cliport.tasks": ROOT / "tasks"}


def sources() -> list[BuildSource]:
    out = []
    for package, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out.append(BuildSource(str(path.relative_to(ROOT)), ".".join([package, *parts])))
    return out


def main() -> int:
    start = time.perf_counter()
    options = Options()
    parse_config_file(options, lambda: None, str(ROOT / "pyproject.toml"), sys.stdout, sys.stderr)
    files = sources()
    try:
        result = build.build(files, options)
        messages = result.errors
    except CompileError as e:
        messages = e.messages
    for line in messages:
        print(line)
    n = sum(": error: " in line for line in messages)
    took = time.perf_counter() - start
    if n:
        print(f"Found {n} errors in {len(files)} source files ({took:.1f} s)")
        return 1
    print(f"Success: no issues found in {len(files)} source files ({took:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
