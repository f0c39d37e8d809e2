"""The README and docs/: every relative link resolves, no history, the code's "design §n" exist.

Links are checked the way a Markdown renderer resolves them: a relative target
is a path from the page's directory (a file or a directory in the repository),
and a ``#fragment`` must be the anchor of a heading of the target page
(GitHub's rule: lower case, punctuation other than ``-`` and ``_`` dropped,
spaces to ``-``, a repeated heading gets ``-1``, ``-2``...).  Links inside
fenced code blocks and inline code are not links.  Reference: CommonMark 0.31,
§6.3 (links), §6.4 (images), §4.5 (fenced code blocks), §6.1 (code spans).
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

REPO = Path(__file__).resolve().parent.parent
PAGES = sorted([REPO / "README.md", REPO / "CHANGELOG.md"] + list((REPO / "docs").glob("*.md")))
USER_PAGES = [p for p in PAGES if p.name != "CHANGELOG.md"]       # no history in these
FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
# [text](target "title") and ![alt](target); the text may hold one level of brackets.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
AUTOLINK_OR_URL = re.compile(r"^(?:[a-z][a-z0-9+.-]*:|//)", re.I)


def outside_fences(text: str) -> list[str]:
    """The lines of ``text`` outside fenced code blocks, as written."""
    out, fence = [], None
    for line in text.splitlines():
        m = FENCE.match(line)
        if fence is None and m:
            fence = m.group(1)
        elif fence is not None:
            if m and m.group(1)[0] == fence[0] and len(m.group(1)) >= len(fence):
                fence = None
        else:
            out.append(line)
    return out


def prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks, with code spans blanked."""
    return [CODE_SPAN.sub(lambda s: " " * len(s.group(0)), line)
            for line in outside_fences(text)]


def slug(heading: str) -> str:
    """A heading's anchor as rendered: code spans keep their text, link syntax
    keeps its text, then lower case, punctuation dropped, spaces to ``-``."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "")
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The fragments of a page's ATX headings (outside code); a repeated one
    gets ``-1``, ``-2``...; an empty set for a file that is not Markdown."""
    if page.suffix != ".md" or not page.is_file():
        return set()
    seen: dict[str, int] = {}
    for line in outside_fences(page.read_text()):
        m = re.match(r"^ {0,3}#{1,6}\s+(.*?)(?:\s+#+)?\s*$", line)
        if m:
            s = slug(m.group(1))
            seen[s] = seen.get(s, 0) + 1
            if seen[s] > 1:
                seen[f"{s}-{seen[s] - 1}"] = 1
    return set(seen)


def links(page: Path) -> list[str]:
    return [m.group(1) for line in prose_lines(page.read_text()) for m in LINK.finditer(line)]


def test_the_pages_are_found_and_have_links():
    names = {p.relative_to(REPO).as_posix() for p in PAGES}
    assert {"README.md", "CHANGELOG.md", "docs/design.md", "docs/node.md", "docs/scenes.md",
            "docs/cli.md", "docs/model.md", "docs/recording.md",
            "docs/performance.md"} <= names
    assert len(links(REPO / "README.md")) > 20


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_relative_link_resolves(page):
    broken = []
    for target in links(page):
        if AUTOLINK_OR_URL.match(target):
            continue                                   # http(s), mailto: not checked here
        path, _, fragment = target.partition("#")
        dest = (page.parent / unquote(path)).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
            continue
        if REPO not in dest.parents and dest != REPO:
            broken.append(f"{target}: outside the repository")
            continue
        if fragment and unquote(fragment) not in anchors(dest):
            broken.append(f"{target}: no heading with that anchor in {dest.name}")
    assert not broken, "\n".join(broken)


def test_anchor_rule_on_known_headings():
    """The slug rule against anchors a renderer gives known headings (GitHub)."""
    page = REPO / "docs" / "design.md"
    found = anchors(page)
    assert "1-the-paper-in-brief" in found
    assert "3-time-integration-linear-solves-constraints-contact" in found
    perf = anchors(REPO / "docs" / "performance.md")
    assert "every-built-in-scene-cloth-lod-bench---scenes" in perf


HISTORY = [
    (re.compile(r"\b(?:this|the last|last|the previous|previous|an earlier|earlier|the next|"
                r"next|the old|old) release\b", re.I), "a release diary"),
    (re.compile(r"\bat filing\b", re.I), "\"at filing\""),
    # A commit hash: 7-40 hex digits with at least one digit and one letter a-f.
    (re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b"), "a commit hash"),
]


@pytest.mark.parametrize("page", USER_PAGES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_no_history_in_the_readme_and_docs(page):
    """History belongs in CHANGELOG.md and git: no commit hashes, no "this/last
    release", no "at filing" in the pages that describe the package as it is."""
    found = [f"line {i}: {what}: {m.group(0)!r}"
             for i, line in enumerate(page.read_text().splitlines(), 1)
             for pattern, what in HISTORY for m in pattern.finditer(line)]
    assert not found, "\n".join(found)


def test_readme_is_short():
    assert len((REPO / "README.md").read_text().splitlines()) <= 400


def test_design_section_references_in_the_code_exist():
    """Code cites docs/design.md as "design §n": every n is a section there."""
    sections = {int(m.group(1)) for m in re.finditer(r"^## (\d+)\. ", (
        REPO / "docs" / "design.md").read_text(), flags=re.M)}
    assert sections >= set(range(1, 11))
    cited = {}
    for path in sorted((REPO / "cloth_lod_ros").rglob("*.py")) + sorted(
            (REPO / "test").glob("*.py")):
        for m in re.finditer(r"design\s+§\s*(\d+)", path.read_text()):
            cited.setdefault(int(m.group(1)), path.relative_to(REPO).as_posix())
    assert cited, "no design § references found"
    missing = {n: where for n, where in cited.items() if n not in sections}
    assert not missing, f"design sections cited but absent: {missing}"
