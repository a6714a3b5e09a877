"""Every relative link and anchor in README.md and docs/ resolves inside the repository, and the README stays a
landing page (at most 120 lines and 1,200 words).

Pure standard library (no cliport import): links are read from the Markdown source, outside code fences and
inline code; external links (any ``scheme:``, e.g. https, mailto, hf) are skipped. A link's path must name a
file or folder inside the repository root, and its anchor must be a heading of the target Markdown file
under GitHub's rule (lowercase, punctuation other than hyphens and underscores dropped, spaces to hyphens,
repeated headings suffixed -1, -2, ...), which mkdocs.yml's slugify follows too.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path
from urllib.parse import unquote

REPO = Path(__file__).resolve().parents[1]

_FENCE = re.compile(r"^\s{0,3}(`{3,}|~{3,})")
_ATX = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)(?:\s+#+)?\s*$")
_SETEXT = re.compile(r"^\s{0,3}(=+|-+)\s*$")
_CODE_SPAN = re.compile(r"(`+)(.+?)\1")
_INLINE_LINK = re.compile(r"\]\(\s*(<[^>]*>|[^)\s]*)(?:\s+(?:\"[^\"]*\"|'[^']*'))?\s*\)")
_REFERENCE_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
_HTML_LINK = re.compile(r"""\b(?:href|src)\s*=\s*["']([^"']*)["']""", re.IGNORECASE)
_HTML_ANCHOR = re.compile(r"""<a\s[^>]*\b(?:name|id)\s*=\s*["']([^"']+)["']""", re.IGNORECASE)
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")
_LIST_ITEM = re.compile(r"^\s*(?:[-*+]|\d+[.)])\s")
_LINE_ANCHOR = re.compile(r"^L\d+(?:-L\d+)?$")


def _prose_lines(text: str, blank_code_spans: bool = True) -> list[tuple[int, str]]:
    """(line number, line) of the lines outside fenced code blocks, inline code spans blanked if asked."""
    lines = []
    fence = None
    for number, line in enumerate(text.splitlines(), start=1):
        match = _FENCE.match(line)
        if fence is None and match:
            fence = match.group(1)
            continue
        if fence is not None:
            if match and match.group(1)[0] == fence[0] and len(match.group(1)) >= len(fence):
                fence = None
            continue
        if blank_code_spans:
            line = _CODE_SPAN.sub(lambda m: " " * len(m.group(0)), line)
        lines.append((number, line))
    return lines


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading (before duplicate suffixes), from the heading's Markdown source."""
    text = _CODE_SPAN.sub(lambda m: m.group(2).strip(), heading)
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links and images: their text
    text = re.sub(r"<[^>]+>", "", text)  # HTML tags
    text = text.replace("*", "")
    text = text.strip().lower()
    kept = []
    for char in text:
        category = unicodedata.category(char)
        if char in "-_ " or category[0] in "LNM":
            kept.append(char)
    return "".join(kept).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every anchor of a Markdown file: its headings' GitHub slugs (with -1, -2 for repeats) and HTML ids."""
    found: set[str] = set()
    counts: dict[str, int] = {}
    previous = ""
    for _, line in _prose_lines(text, blank_code_spans=False):  # code spans belong to slugs
        heading = None
        atx = _ATX.match(line)
        if atx:
            heading = atx.group(2)
        elif _SETEXT.match(line) and previous.strip() and "|" not in previous and not _LIST_ITEM.match(previous):
            heading = previous.strip()
        if heading is not None:
            slug = github_slug(heading)
            n = counts.get(slug, 0)
            counts[slug] = n + 1
            found.add(slug if n == 0 else f"{slug}-{n}")
        found.update(_HTML_ANCHOR.findall(line))
        previous = line if not atx else ""
    return found


def links(text: str) -> list[tuple[int, str]]:
    """(line number, destination) of every inline, reference-definition and HTML link outside code."""
    found = []
    for number, line in _prose_lines(text):
        for pattern in (_INLINE_LINK, _REFERENCE_DEF, _HTML_LINK):
            for match in pattern.finditer(line):
                destination = match.group(1).strip()
                if destination.startswith("<") and destination.endswith(">"):
                    destination = destination[1:-1].strip()
                found.append((number, destination))
    return found


def check(root: Path, files: list[Path]) -> list[str]:
    """Every broken relative link of ``files`` as 'FILE:LINE: DESTINATION: why'; empty when all resolve."""
    root = root.resolve()
    problems = []
    anchor_cache: dict[Path, set[str]] = {}

    def anchors_of(path: Path) -> set[str]:
        if path not in anchor_cache:
            anchor_cache[path] = anchors(path.read_text(encoding="utf-8"))
        return anchor_cache[path]

    for source in files:
        source = source.resolve()
        name = source.relative_to(root).as_posix()
        for number, destination in links(source.read_text(encoding="utf-8")):
            where = f"{name}:{number}: {destination or '(empty)'}"
            if _SCHEME.match(destination) or destination.startswith("//"):
                continue  # external: https, mailto, hf, ...
            path_part, _, fragment = destination.partition("#")
            path_part = unquote(path_part.split("?", 1)[0])
            if not path_part and not fragment:
                problems.append(f"{where}: empty link")
                continue
            target = (source.parent / path_part).resolve() if path_part else source
            if not target.is_relative_to(root):
                problems.append(f"{where}: points outside the repository")
                continue
            if not target.exists():
                problems.append(f"{where}: no such file or folder")
                continue
            if not fragment:
                continue
            fragment = unquote(fragment)
            if target.is_file() and target.suffix.lower() in (".md", ".markdown"):
                if fragment not in anchors_of(target):
                    problems.append(f"{where}: no heading or anchor #{fragment} in {target.relative_to(root)}")
            elif not (target.is_file() and _LINE_ANCHOR.match(fragment)):
                problems.append(f"{where}: anchor #{fragment} on a file that is not Markdown")
    return problems


def markdown_files(root: Path) -> list[Path]:
    """README.md and every Markdown file under docs/."""
    files = [root / "README.md"]
    files += sorted(p for p in (root / "docs").rglob("*") if p.is_file() and p.suffix.lower() in (".md", ".markdown"))
    return files


def test_readme_and_docs_links_resolve() -> None:
    files = markdown_files(REPO)
    assert len(files) > 1, "docs/ has no Markdown pages"
    problems = check(REPO, files)
    assert not problems, "broken links:\n" + "\n".join(problems)


#: The README is a landing page: what it is, the pictures, the two commands, one snippet, the command table and
#: three measured headlines. Guides go to docs/, measurements to docs/results/.
README_MAX_LINES = 120
README_MAX_WORDS = 1200


def test_readme_is_a_landing_page() -> None:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    lines, words = len(text.splitlines()), len(text.split())
    assert lines <= README_MAX_LINES and words <= README_MAX_WORDS, (
        f"README.md has {lines} lines and {words} words (at most {README_MAX_LINES} and {README_MAX_WORDS}); "
        "move guides to docs/ and measurements to docs/results/"
    )


def test_github_slugs() -> None:
    assert github_slug("Training recipes (one GPU)") == "training-recipes-one-gpu"
    slug = github_slug("Ecosystem: Gymnasium, TensorBoard, safetensors")
    assert slug == "ecosystem-gymnasium-tensorboard-safetensors"
    assert github_slug("`cliport-eval` and two_stream") == "cliport-eval-and-two_stream"
    assert github_slug("A - B") == "a---b"
    assert github_slug("[Parity](parity.md) **now**") == "parity-now"
    assert github_slug("Über 3.0!") == "über-30"
    text = '# Notes\n\n## Notes\n\nSetext\n------\n\n```\n# not a heading\n```\n\n<a name="here"></a>\n\n## Notes\n'
    assert anchors(text) == {"notes", "notes-1", "notes-2", "setext", "here"}


def test_checker_finds_broken_links_and_anchors(tmp_path: Path) -> None:
    root = tmp_path / "repo"
    (root / "docs" / "pictures").mkdir(parents=True)
    (root / "docs" / "pictures" / "a.png").write_bytes(b"")
    (tmp_path / "outside.md").write_text("# Outside\n")
    (root / "docs" / "page.md").write_text("# Page\n\n## Some section\n\nBack to the [top](#page).\n")
    (root / "README.md").write_text(
        "# Project\n\n"
        "A [good link](docs/page.md), a [good anchor](docs/page.md#some-section), ![a picture](docs/pictures/a.png),\n"
        "a [same-page anchor](#project) and [external](https://example.com/x.md) [mail](mailto:a@b.c).\n"
        "A [broken link](docs/missing.md) and a [broken anchor](docs/page.md#no-such-section).\n"
        "A [same-page miss](#nothing), a [way out](../outside.md) and ![a missing picture](docs/pictures/b.png).\n"
        "`[in code](docs/missing.md)`\n\n"
        "```\n[in a fence](docs/missing.md)\n```\n"
    )
    problems = check(root, markdown_files(root))
    assert problems == [
        "README.md:5: docs/missing.md: no such file or folder",
        "README.md:5: docs/page.md#no-such-section: no heading or anchor #no-such-section in docs/page.md",
        "README.md:6: #nothing: no heading or anchor #nothing in README.md",
        "README.md:6: ../outside.md: points outside the repository",
        "README.md:6: docs/pictures/b.png: no such file or folder",
    ]
    (root / "README.md").write_text("# Project\n\nOnly [good](docs/page.md#some-section) links.\n")
    assert check(root, markdown_files(root)) == []
