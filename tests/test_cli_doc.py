"""docs/cli.md's table of exit statuses is :class:`services.exits.ExitStatus`, row for member:
a status added, renumbered or renamed in the code fails here until the page says it. Plain and
fast: no zenoh session."""

from __future__ import annotations

import re
from pathlib import Path

from services.exits import ExitStatus

CLI_PAGE = Path(__file__).resolve().parent.parent / "docs" / "cli.md"
ROW = re.compile(r"^\| (\d+) \| `(\w+)` \| (.+) \|$")


def documented_statuses(page: str) -> dict[str, int]:
    """The rows of the ``## Exit status`` section: name -> number."""
    section = page.split("## Exit status", 1)[1].split("\n## ", 1)[0]
    rows = [ROW.match(line) for line in section.splitlines()]
    return {row.group(2): int(row.group(1)) for row in rows if row}


def test_the_exit_status_table_lists_every_status_by_its_name_and_number():
    documented = documented_statuses(CLI_PAGE.read_text(encoding="utf-8"))
    assert documented == {status.name: status.value for status in ExitStatus}


def test_a_missing_or_renumbered_row_is_seen():
    page = "## Exit status\n\n| status | name | meaning |\n|---|---|---|\n| 0 | `OK` | done |\n| 3 | `FAILURE` | x |\n"
    assert documented_statuses(page) == {"OK": 0, "FAILURE": 3}
    assert documented_statuses(page) != {status.name: status.value for status in ExitStatus}
