"""The documentation's links hold: every relative link of README.md, docs/ and reports/ names a
file that exists (and, with an anchor, a heading of that file), and every docs/ or reports/ page
the code, configs and tests point to exists."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")),
         *sorted((REPO / "reports").glob("*.md"))]
SOURCE_DIRS = ("eaglemission", "drivers", "detectors", "estimators", "missions", "lab", "configs",
               "benchmarks", "tests")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", flags=re.S | re.M)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    seen: dict[str, int] = {}
    out: set[str] = set()
    for line in text.splitlines():
        m = re.match(r"#{1,6} (.+)", line)
        if not m:
            continue
        base = slug(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(page: Path) -> list[str]:
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    return [m.group(1) for m in LINK.finditer(text)]


def test_every_relative_link_and_anchor_resolves() -> None:
    broken = []
    for page in PAGES:
        for target in links(page):
            if re.match(r"[a-z]+://|mailto:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(REPO)}: {target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{page.relative_to(REPO)}: {target}: no such heading")
    assert not broken, "\n".join(broken)


def test_the_pages_the_code_points_to_exist() -> None:
    ref = re.compile(r"\b((?:docs|reports)/[A-Za-z0-9_]+\.md)\b")
    missing = []
    for folder in SOURCE_DIRS:
        for f in sorted((REPO / folder).rglob("*")):
            if f.suffix not in (".py", ".yaml") or "__pycache__" in f.parts:
                continue
            for m in ref.finditer(f.read_text(encoding="utf-8", errors="replace")):
                if not (REPO / m.group(1)).exists():
                    missing.append(f"{f.relative_to(REPO)}: {m.group(1)}")
    assert not missing, "\n".join(missing)


def test_the_checks_can_fail(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# Top\n\n## A `code` (title), too\n\n[x](other.md) [y](#a-code-title-too) "
                    "[z](#nope)\n```\n# not a heading\n```\n", encoding="utf-8")
    assert anchors(page) == {"top", "a-code-title-too"}
    assert links(page) == ["other.md", "#a-code-title-too", "#nope"]
