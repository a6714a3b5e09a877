"""The project's prose speaks to users: README.md, docs/, CHANGELOG.md, the scripts, the configs' comments and the
notebooks' Markdown cells tell what is true now and where the measurements are, never how the project was developed
(which working session, which borrowed machine, how much machine time, "machine A"). Hardware is named as hardware
("2-core AMD EPYC (family 26, Zen 5, AVX-512)", "NVIDIA H200").

Pure standard library (no cliport import). Each phrase is a regular expression, matched case-insensitively over a
whole file (so a phrase broken over two lines is found) and reported with its file and line (in a notebook, the line
of its Markdown cells' text).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Phrases that tell how the project was developed, each with what to write instead.
HISTORY_PHRASES: dict[str, str] = {
    # "session" is not a word of this project's APIs; "possession" and "sessional" do not match.
    r"\bsessions?\b": "say what was measured and when (a date), not in which working session",
    # Case-sensitive letter: "machine a run can train" is fine, "machine A" is not.
    r"\bmachines?\s+(?-i:[AB])\b": "name the hardware (CPU model, family, flags; GPU model)",
    r"\bdevelopment\s+machines?\b": "name the hardware (CPU model, family, flags; GPU model)",
    r"\blent\b|\bborrow(?:ed|ing)?\b": "name the hardware, not how it was had",
    # "device time" alone is the profiler's (operations by device time): only its use as a budget is history.
    r"\b(?:minutes|seconds|hours)\s+of\s+(?:device|machine|GPU)\s+time\b": "say how long it took, not whose time",
    r"\b(?:device|machine)\s+time\s+(?:ran|runs|run)\s+out\b|\bdevice[-\s]time\s+budget\b": "say what was not measured",
    r"\b(?:this|next|last|previous|that)\s+round\b": "say what is true now, or give the date and the commit",
    r"\bissues?\s+#?\d+\b": "an issue number means nothing to a user: say what changed, or cite a commit",
    r"\b(?-i:I)\s+(?:ran|tried|measured|found)\b": "write what was measured, not who did it",
    r"\bscratch\s+(?:scripts?|diagnostics?)\b": "name the script a user can run, or leave it out",
}
_PATTERN = re.compile("|".join(f"(?:{p})" for p in HISTORY_PHRASES), re.IGNORECASE)


def prose_files(root: Path) -> list[Path]:
    """README.md, CHANGELOG.md, every Markdown file under docs/, every file in scripts/, configs/*.toml and the
    notebooks."""
    files = [root / "README.md", root / "CHANGELOG.md"]
    files += sorted(p for p in (root / "docs").rglob("*.md") if p.is_file())
    files += sorted(p for p in (root / "scripts").iterdir() if p.is_file())
    files += sorted((root / "configs").glob("*.toml"))
    files += sorted((root / "notebooks").glob("*.ipynb"))
    return [p for p in files if p.exists()]


def _text(path: Path) -> str:
    """The prose of a file: a notebook's Markdown cells (its code cells are code), any other file whole."""
    text = path.read_text(encoding="utf-8")
    if path.suffix != ".ipynb":
        return text
    cells = json.loads(text)["cells"]
    return "\n".join("".join(cell["source"]) for cell in cells if cell["cell_type"] == "markdown")


def history_phrases(root: Path, files: list[Path]) -> list[str]:
    """'FILE:LINE: "phrase": what to write instead' for every history phrase in ``files``."""
    found = []
    for path in files:
        text = _text(path)
        name = path.relative_to(root).as_posix()
        for match in _PATTERN.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            advice = next(a for p, a in HISTORY_PHRASES.items() if re.fullmatch(p, match.group(0), re.IGNORECASE))
            phrase = " ".join(match.group(0).split())
            found.append(f'{name}:{line}: "{phrase}": {advice}')
    return found


def test_no_development_history_in_the_prose() -> None:
    files = prose_files(REPO)
    assert len(files) > 10
    found = history_phrases(REPO, files)
    assert not found, "the project's prose tells how it was developed:\n" + "\n".join(found)


@pytest.mark.parametrize(
    "text, line",
    [
        ("Measured in the fifth session of 2026-11-28.", 3),
        ("It took 15 minutes of device time.", 3),
        ("Then the device time ran out.", 3),
        ("A is the earlier one; machine B is faster.", 3),
        ("on the 2-core development machine", 3),
        ("on a lent H200", 3),
        ("a borrowed GPU", 3),
        ("Until this round the test passed.", 3),
        ("the targets of issue 42", 3),
        ("I ran an 8-second test beside its probe.", 3),
        ("a scratch diagnostic beside the runs", 3),
        ("measured on a GPU\nsession's machine", 4),
        ("fifteen minutes\nof device time", 3),
    ],
)
def test_each_phrase_is_found(tmp_path: Path, text: str, line: int) -> None:
    (tmp_path / "docs").mkdir()
    page = tmp_path / "docs" / "page.md"
    page.write_text("# Page\n\n" + text + "\n")
    found = history_phrases(tmp_path, [page])
    assert len(found) == 1 and found[0].startswith(f"docs/page.md:{line}: "), found


@pytest.mark.parametrize(
    "text",
    [
        "The possession of a checkpoint; a sessional note.",
        "on a fresh GPU machine a run can train while PyBullet builds",
        "the top operations by device time (the profiler's)",
        "2-core AMD EPYC (family 26, Zen 5, AVX-512) and one NVIDIA H200",
        "rounds to the nearest cell; round bowls",
        "a silent failure; an excellent result",
        "Issues are welcome.",
    ],
)
def test_ordinary_prose_passes(tmp_path: Path, text: str) -> None:
    page = tmp_path / "page.md"
    page.write_text(text + "\n")
    assert history_phrases(tmp_path, [page]) == []


def test_a_notebook_is_read_by_its_markdown_cells(tmp_path: Path) -> None:
    cells = [
        {"cell_type": "markdown", "source": ["# Title\n", "Run it on the development machine.\n"]},
        {"cell_type": "code", "source": ["session = make_session()  # code may say session\n"]},
    ]
    notebook = tmp_path / "nb.ipynb"
    notebook.write_text(json.dumps({"cells": cells}))
    found = history_phrases(tmp_path, [notebook])
    assert len(found) == 1 and found[0].startswith('nb.ipynb:2: "development machine"'), found
