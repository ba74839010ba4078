"""The README is a front door and docs/ its rooms: every link resolves, every page is reached
from the README, and nothing refers to how the work was organised."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lowercase, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", text, re.M)}


def links(page: Path) -> list[str]:
    return LINK.findall(FENCE.sub("", page.read_text()))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_and_anchor_resolves(page):
    for link in links(page):
        if re.match(r"[a-z]+:", link):
            continue  # https:, mailto:
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        assert target.exists(), f"{page.name}: {link} does not exist"
        if anchor:
            assert target.suffix == ".md", f"{page.name}: {link}: an anchor in a non-page"
            assert anchor in anchors(target), f"{page.name}: no heading for {link}"


def test_the_readme_is_a_front_door_to_every_page():
    readme = ROOT / "README.md"
    assert len(readme.read_text().splitlines()) <= 300
    reached = {(ROOT / link.partition("#")[0]).resolve() for link in links(readme)}
    for page in PAGES[1:]:
        assert page.resolve() in reached, f"the README does not link {page.name}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_page_refers_to_how_the_work_was_organised(page):
    text = page.read_text()
    assert not re.search(r"\bissues? #?\d+|(?<![\w/])#\d+\b", text, re.I), page.name


def test_slugs_follow_githubs_rules():
    assert slug("The paper's experiment") == "the-papers-experiment"
    assert slug("Plain SARSA(λ) on the four tasks") == "plain-sarsaλ-on-the-four-tasks"
    assert slug("2026-11-22: goal sectors in the state") == "2026-11-22-goal-sectors-in-the-state"
