"""Every relative link of the documentation leads somewhere: the README, docs/, msg_docs/ and bags/README.md link
files that exist and, after a '#', headings that exist in them (GitHub's anchors). A newcomer follows the README's
links first; a page moved or renamed must not leave them dangling."""
from __future__ import annotations

import re
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", ROOT / "bags" / "README.md", *(ROOT / "docs").rglob("*.md"),
                *(ROOT / "msg_docs").glob("*.md")])

#: [text](target) and ![alt](target); the target ends at whitespace or ')' (an optional "title" is ignored)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)


def prose(text: str) -> str:
    """The text without fenced code blocks and code spans (a `[x](y)` in code is not a link)."""
    return CODE_SPAN.sub("", FENCE.sub("", text))


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, markup and punctuation dropped (not '-' or '_'), spaces -> '-'."""
    text = re.sub(r"[`*]", "", heading.strip()).lower()
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)            # a link in a heading: its text
    kept = "".join(c for c in text if c in " -_" or unicodedata.category(c)[0] in "LN")
    return kept.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            a = anchor(m.group(1))
            out.add(a if a not in seen else f"{a}-{seen[a]}")          # GitHub numbers repeated headings
            seen[a] = seen.get(a, 0) + 1
    return out


def broken_links(page: Path, root: Path = ROOT) -> list[str]:
    """The relative links of ``page`` that lead nowhere, each as 'target: why'."""
    bad = []
    for target in LINK.findall(prose(page.read_text(encoding="utf-8"))):
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):     # http:, https:, mailto:, ws: ...
            continue
        path, _, frag = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file {dest.relative_to(root) if dest.is_relative_to(root) else dest}")
        elif frag and dest.suffix == ".md" and frag not in anchors(dest):
            bad.append(f"{target}: no heading with the anchor #{frag} in {dest.relative_to(root)}")
    return bad


def test_the_pages_are_found():
    names = {p.relative_to(ROOT).as_posix() for p in PAGES}
    assert {"README.md", "docs/usage.md", "docs/speed.md", "msg_docs/sim_node.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_leads_to_a_file_and_heading(page):
    assert broken_links(page) == [], f"{page.relative_to(ROOT)} has links that lead nowhere"


def test_the_checker_sees_a_broken_link(tmp_path):
    (tmp_path / "other.md").write_text("# Managed node (lifecycle)\n## The `steady` solver, in short\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](other.md) [ok](other.md#managed-node-lifecycle) [ok](other.md#the-steady-solver-in-short)\n"
                    "![gone](figures/missing.png) [bad anchor](other.md#no-such-heading) [web](https://x.org/a)\n"
                    "`[in code](nowhere.md)`\n```\n[in a block](nowhere.md)\n```\n")
    assert broken_links(page, tmp_path) == [
        "figures/missing.png: no such file figures/missing.png",
        "other.md#no-such-heading: no heading with the anchor #no-such-heading in other.md",
    ]


def test_the_readme_stays_a_five_minute_read():
    """Issue 19: what a newcomer needs, at most ~200 lines; the reference material lives in docs/."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= 200, f"README.md has {lines} lines: move the detail to a page of docs/ and link it"
