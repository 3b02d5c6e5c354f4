"""Every relative link in README.md and docs/**/*.md resolves: the file it names exists and, when
the link has a ``#anchor``, the page it names has a heading whose GitHub anchor is that. Plain and
fast: no zenoh session.

The anchor of a heading is GitHub's: its text as rendered (code spans, emphasis and links reduced
to their text), lower case, every character but letters, digits, ``-``, ``_`` and spaces dropped,
spaces turned to ``-``; a heading whose anchor an earlier heading of the page already has gets
``-1``, ``-2``, ... Lines inside fenced code blocks are neither headings nor links.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
README_MAX_LINES = 150
"""The README is a front door (what it is, how to run it, where to read on), not a reference."""

_FENCE = re.compile(r"^ {0,3}(```|~~~).*?^ {0,3}\1[^\n]*$", re.MULTILINE | re.DOTALL)
_CODE_SPAN = re.compile(r"(`+)(?!`).*?(?<!`)\1(?!`)", re.DOTALL)
_HEADING = re.compile(r"^ {0,3}#{1,6}[ \t]+(.+?)(?:[ \t]+#+)?[ \t]*$", re.MULTILINE)
_INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+\"[^\"]*\")?\s*$", re.MULTILINE)
_EXTERNAL = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
"""A URL with a scheme (``https:``, ``mailto:``): not a file of the repository."""


def without_code_blocks(markdown: str) -> str:
    return _FENCE.sub("", markdown)


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading with this Markdown text."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link or image: its text
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML
    text = text.replace("`", "").replace("*", "")
    text = re.sub(r"(?<!\w)_+|_+(?!\w)", "", text)  # _emphasis_, not snake_case
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(markdown: str) -> set[str]:
    """Every anchor the page's headings have, duplicates numbered as GitHub numbers them."""
    seen: Counter[str] = Counter()
    result = set()
    for heading in _HEADING.findall(without_code_blocks(markdown)):
        anchor = slug(heading)
        result.add(f"{anchor}-{seen[anchor]}" if seen[anchor] else anchor)
        seen[anchor] += 1
    return result


def link_targets(markdown: str) -> list[str]:
    """The targets of the page's inline links, images and reference definitions, outside code."""
    text = _CODE_SPAN.sub("", without_code_blocks(markdown))
    return _INLINE_LINK.findall(text) + _REFERENCE.findall(text)


def broken_links(page: Path, markdown: str) -> list[str]:
    """The relative links of ``page`` (its text ``markdown``) that name no file, or a heading
    its page does not have."""
    broken = []
    for target in link_targets(markdown):
        if _EXTERNAL.match(target):
            continue
        path, _, anchor = target.partition("#")
        if not path:  # a heading of this page
            linked, text = page, markdown
        else:
            linked = (page.parent / path).resolve()
            if not linked.exists():
                broken.append(f"{target}: no such file")
                continue
            text = linked.read_text(encoding="utf-8") if anchor and linked.suffix == ".md" else ""
        if anchor and linked.suffix == ".md" and anchor not in anchors(text):
            broken.append(f"{target}: no heading #{anchor} in {linked.name}")
    return broken


# --- The anchor of a heading ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("heading", "anchor"),
    [
        ("2.7 Rates: the control path and the observed steps", "27-rates-the-control-path-and-the-observed-steps"),
        ("Calibration: UMBmark (`invent calibrate umbmark`)", "calibration-umbmark-invent-calibrate-umbmark"),
        ("lockstep (default)", "lockstep-default"),
        ("report.json", "reportjson"),
        ("Versions, and what was checked how", "versions-and-what-was-checked-how"),
        ("`invent up`", "invent-up"),
        ("Parameters (`[sim]`)", "parameters-sim"),
        ("Status (`invent call invent/rh0/sim/status`)", "status-invent-call-inventrh0simstatus"),
        ("Measuring by hand (`--measured FILE`)", "measuring-by-hand---measured-file"),
        ("`target_angle`: `seed` and `integrated`", "target_angle-seed-and-integrated"),
        ("12. The ROS 2 bridge", "12-the-ros-2-bridge"),
    ],
)
def test_the_anchor_of_a_heading_the_docs_use_is_githubs(heading: str, anchor: str) -> None:
    assert slug(heading) == anchor


def test_headings_with_the_same_anchor_are_numbered_in_order() -> None:
    page = "# Bad input\n\n## Keys\n\ntext\n\n## Keys\n\n### Keys\n"
    assert anchors(page) == {"bad-input", "keys", "keys-1", "keys-2"}


def test_a_comment_in_a_code_block_is_no_heading() -> None:
    page = "# Fleets\n\n```toml\n# fleet.toml\nworld = 'empty'\n```\n"
    assert anchors(page) == {"fleets"}


# --- The checker, on small pages ------------------------------------------------------------------


def _site(tmp_path: Path) -> Path:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "sim.md").write_text("# Simulator\n\n## Determinism\n\n### lockstep (default)\n")
    (tmp_path / "image.png").write_bytes(b"\x89PNG")
    return docs / "page.md"


def test_links_that_resolve_pass(tmp_path: Path) -> None:
    page = _site(tmp_path)
    text = (
        "# Page\n\n## Here\n\n[sim](sim.md), [lockstep](sim.md#lockstep-default), [here](#here),\n"
        "![a plot](../image.png), [zenoh](https://zenoh.io), [mail](mailto:a@b.c)\n\n[ref]: sim.md#determinism\n"
    )
    assert broken_links(page, text) == []


def test_a_link_to_a_missing_file_is_caught(tmp_path: Path) -> None:
    page = _site(tmp_path)
    assert broken_links(page, "[gone](motor.md) and ![gone](images/gone.png)\n") == [
        "motor.md: no such file",
        "images/gone.png: no such file",
    ]


def test_a_link_to_a_missing_heading_is_caught(tmp_path: Path) -> None:
    page = _site(tmp_path)
    text = "# Page\n\n[old](sim.md#lockstep) and [self](#nowhere) and [ok](#page)\n"
    assert broken_links(page, text) == [
        "sim.md#lockstep: no heading #lockstep in sim.md",
        "#nowhere: no heading #nowhere in page.md",
    ]


def test_links_inside_code_are_not_checked(tmp_path: Path) -> None:
    page = _site(tmp_path)
    text = "`[not](a-link.md)` and\n\n```md\n[nor](this.md)\n```\n"
    assert broken_links(page, text) == []


# --- The repository's pages -----------------------------------------------------------------------


def test_every_relative_link_in_the_readme_and_the_docs_resolves() -> None:
    broken = [
        f"{page.relative_to(ROOT)}: {problem}"
        for page in PAGES
        for problem in broken_links(page, page.read_text(encoding="utf-8"))
    ]
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_the_readme_is_a_front_door_that_links_the_reference_pages() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= README_MAX_LINES
    linked = {target.partition("#")[0] for target in link_targets(readme)}
    assert {"docs/cli.md", "docs/recording.md", "docs/security.md"} <= linked
