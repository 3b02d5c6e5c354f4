"""docs/protocol.md documents every key, token, method and message type the code declares, and the
repository points to no contract outside itself. Plain and fast: no zenoh session.

The expected strings are built from the code (the enums of ``schemas.keys`` and ``Keys``), so a key
added to the code fails here until it is documented.
"""

from __future__ import annotations

import re
import subprocess
from collections import Counter
from pathlib import Path

import msgspec
import pytest

from schemas.codec import MESSAGE_TYPES
from schemas.keys import Keys, Service
from schemas.topics import METHOD_ARGUMENTS, TOPIC_TYPES, Method, MethodFamily, Topic
from services.clock.lockstep import OUTPUTS

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "docs" / "protocol.md"

ROBOT = "ROBOT"
"""A valid robot name standing for ``<robot>``, which ``Keys`` refuses (not one key chunk)."""
KEYS = Keys(ROBOT)
PREFIX = f"{KEYS.prefix}/"
DOC_PREFIX = "invent/<robot>/"


@pytest.fixture(scope="module")
def doc() -> str:
    return PROTOCOL.read_text(encoding="utf-8")


def relative(key: str) -> str:
    """``invent/ROBOT/motor/torque`` -> ``motor/torque``."""
    assert key.startswith(PREFIX), key
    return key.removeprefix(PREFIX)


def documented(key: str) -> str:
    """``invent/ROBOT/motor/torque`` -> ``invent/<robot>/motor/torque``, as the page writes it."""
    return DOC_PREFIX + relative(key)


def test_every_topic_is_documented(doc: str) -> None:
    missing = [
        str(topic)
        for topic in Topic
        if documented(KEYS.topic(topic)) not in doc and f"`{relative(KEYS.topic(topic))}`" not in doc
    ]
    assert not missing, f"data keys not in {PROTOCOL.name}: {missing}"


def test_every_status_queryable_and_alive_token_is_documented(doc: str) -> None:
    missing = [
        relative(key)
        for service in Service
        for key in (KEYS.status(service), KEYS.alive(service))
        if relative(key) not in doc
    ]
    assert not missing, f"status keys or liveliness tokens not in {PROTOCOL.name}: {missing}"
    assert documented(KEYS.status(Service.MOTOR)).replace(Service.MOTOR, "<service>") in doc
    assert documented(KEYS.alive(Service.MOTOR)).replace(Service.MOTOR, "<service>") in doc


def test_the_view_status_is_documented(doc: str) -> None:
    assert documented(KEYS.view_status) in doc


def test_the_ticks_tokens_are_documented(doc: str) -> None:
    any_rate = relative(KEYS.ticks_at_any_rate(Service.DRIVE))
    assert any_rate.endswith("/*"), any_rate
    template = documented(KEYS.ticks_at_any_rate(Service.DRIVE)).replace("/*", "/<rate_hz>")
    assert template.replace(Service.DRIVE, "<service>") in doc
    missing = [
        str(service)
        for service in OUTPUTS
        if relative(KEYS.ticks_at_any_rate(service)).replace("/*", "/<rate_hz>") not in doc
    ]
    assert not missing, f"lockstep participants' ticks tokens not in {PROTOCOL.name}: {missing}"


def test_every_motor_method_is_documented(doc: str) -> None:
    missing = [
        relative(KEYS.method(family, method))
        for family in MethodFamily
        for method in Method
        if relative(KEYS.method(family, method)) not in doc
    ]
    assert not missing, f"Motor method keys not in {PROTOCOL.name}: {missing}"


def test_every_message_type_and_field_is_documented(doc: str) -> None:
    types = {*TOPIC_TYPES.values(), *METHOD_ARGUMENTS.values(), *MESSAGE_TYPES}
    missing_types = sorted(t.__name__ for t in types if f"`{t.__name__}`" not in doc and f"**{t.__name__}**" not in doc)
    assert not missing_types, f"message types not in {PROTOCOL.name}: {missing_types}"
    missing_fields = sorted(
        f"{t.__name__}.{field.name}"
        for t in types
        for field in msgspec.structs.fields(t)
        if f"`{field.name}`" not in doc
    )
    assert not missing_fields, f"message fields not in {PROTOCOL.name}: {missing_fields}"


def test_the_section_numbering_the_code_cites_is_there(doc: str) -> None:
    headings = re.findall(r"^## (\d+)\. ", doc, flags=re.MULTILINE)
    assert [int(number) for number in headings[:9]] == list(range(1, 10))
    items = re.findall(r"^### 9\.(\d+) ", doc, flags=re.MULTILINE)
    assert [int(number) for number in items[:8]] == list(range(1, 9))


# --- Markdown anchors -----------------------------------------------------------------------------


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(markdown: str) -> set[str]:
    markdown = re.sub(r"^```.*?^```", "", markdown, flags=re.MULTILINE | re.DOTALL)
    seen: Counter[str] = Counter()
    result = set()
    for heading in re.findall(r"^#{1,6} (.+)$", markdown, flags=re.MULTILINE):
        anchor = github_anchor(heading)
        result.add(anchor if not seen[anchor] else f"{anchor}-{seen[anchor]}")
        seen[anchor] += 1
    return result


def test_links_into_the_protocol_page_resolve(doc: str) -> None:
    """Every ``protocol.md#anchor`` link in the Markdown files, and every ``#anchor`` link of the
    page itself, names a heading of docs/protocol.md."""
    targets = anchors(doc)
    broken = [f"protocol.md#{a}" for a in re.findall(r"\]\(#([^)\s]+)\)", doc) if a not in targets]
    for path in tracked_files():
        if path.suffix == ".md" and path != PROTOCOL and path.exists():
            text = path.read_text(encoding="utf-8")
            broken += [
                f"{path.relative_to(ROOT)}: protocol.md#{a}"
                for a in re.findall(r"protocol\.md#([^)\s]+)\)", text)
                if a not in targets
            ]
    assert not broken, f"links to missing headings of {PROTOCOL.name}: {broken}"


# --- No external contract -------------------------------------------------------------------------

_OUTSIDE = re.compile("|".join([re.escape(".." + "/shared"), r"\b" + "SP" + "EC" + r"\b"]))
"""A path out of the repository to the shared folder, or the name of the external document the
code once cited (spelled in pieces, so this file does not match itself)."""


def tracked_files() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [ROOT / name for name in listed.decode().split("\0") if name]


def _text(path: Path) -> str | None:
    """The file's text, or None for a binary, unreadable or deleted file."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def test_no_tracked_file_points_outside_the_repository() -> None:
    hits = []
    for path in tracked_files():
        text = _text(path)
        if text is None:
            continue
        for number, line in enumerate(text.splitlines(), start=1):
            if _OUTSIDE.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not hits, "references to a contract outside the repository (cite docs/protocol.md):\n" + "\n".join(hits)
