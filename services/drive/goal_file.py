"""Goal files: goals and cancels sent to the drive at fixed simulation times (pure, no zenoh).

``invent drive --goal-file FILE`` sends each entry at the first drive tick at or after its ``at``,
through the same path as a query on ``drive/goal/send`` or ``drive/goal/cancel`` (docs/protocol.md
section 7.3), so a lockstep run of a goal file is as deterministic as a scenario's::

    [[goals]]
    at = 0.0          # simulated seconds
    x = 1.5
    y = 0.5
    theta = 1.57      # optional; and frame, position_tolerance, heading_tolerance, time_limit, id

    [[goals]]
    at = 4.0
    cancel = true     # cancels whatever runs (or `id = "..."`)

A file is loaded strictly: an unknown key, a wrong type, ``at`` out of order, an ``at`` or
``time_limit`` beyond ``MAX_GOAL_SECONDS`` (schemas/messages.py), or a goal without ``x`` and ``y``
is a ConfigError naming the entry. What a goal says is checked when it is sent, as a query's would
be: a goal the drive rejects is logged with the reason and the file goes on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import msgspec

from schemas.messages import NANOSECONDS_PER_SECOND, GoalId
from schemas.navigation import MAX_GOAL_SECONDS, CancelRequest, GoalRequest
from services.config import ConfigError, convert_toml

MAX_GOAL_FILE_ENTRIES = 10_000


class GoalFileEntry(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    at: Annotated[float, msgspec.Meta(ge=0.0, le=MAX_GOAL_SECONDS)]
    """Simulated seconds from the start of the run."""
    cancel: bool = False
    x: float | None = None
    y: float | None = None
    theta: float | None = None
    frame: str = "map"
    position_tolerance: float | None = None
    heading_tolerance: float | None = None
    time_limit: Annotated[float, msgspec.Meta(le=MAX_GOAL_SECONDS)] | None = None
    id: GoalId = ""

    def request(self) -> GoalRequest | CancelRequest:
        """What the entry sends: a cancel, or a goal."""
        if self.cancel:
            return CancelRequest(self.id)
        assert self.x is not None and self.y is not None
        return GoalRequest(
            x=self.x,
            y=self.y,
            theta=self.theta,
            frame=self.frame,
            position_tolerance=self.position_tolerance,
            heading_tolerance=self.heading_tolerance,
            time_limit=self.time_limit,
            id=self.id,
        )


class GoalFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    goals: Annotated[list[GoalFileEntry], msgspec.Meta(min_length=1, max_length=MAX_GOAL_FILE_ENTRIES)]
    name: str = ""


def parse_goal_file(text: str, source: str = "goal file") -> GoalFile:
    """A goal file from TOML; ConfigError naming the entry that is wrong."""
    goal_file = convert_toml(text, GoalFile, source)
    previous = 0.0
    for index, entry in enumerate(goal_file.goals):
        where = f"{source}: goals[{index}]"
        if entry.at < previous:
            raise ConfigError(
                f"{where}: `at` = {entry.at} is before the entry above it ({previous}): list them in order"
            )
        previous = entry.at
        goal_fields = ("x", "y", "theta", "position_tolerance", "heading_tolerance", "time_limit")
        if entry.cancel and any(getattr(entry, name) is not None for name in goal_fields):
            raise ConfigError(f"{where}: a cancel takes only `at` and `id`")
        if not entry.cancel and (entry.x is None or entry.y is None):
            raise ConfigError(f"{where}: a goal needs `x` and `y` (or `cancel = true`)")
    return goal_file


def load_goal_file(path: str) -> GoalFile:
    """:func:`parse_goal_file` of the file at ``path``; ConfigError when it cannot be read."""
    try:
        text = Path(path).read_text()
    except OSError as error:
        raise ConfigError(f"goal file {path!r}: {error.strerror}") from None
    goal_file = parse_goal_file(text, path)
    return goal_file if goal_file.name else msgspec.structs.replace(goal_file, name=Path(path).stem)


class GoalSchedule:
    """The entries of a goal file still to send: :meth:`due` gives those whose time has come."""

    def __init__(self, goal_file: GoalFile) -> None:
        self.entries = goal_file.goals
        self.sent = 0

    @property
    def exhausted(self) -> bool:
        return self.sent >= len(self.entries)

    def due(self, elapsed_ns: int) -> list[GoalFileEntry]:
        """The entries at or before ``elapsed_ns`` (simulated ns since the run started) not yet sent."""
        start = self.sent
        while (
            self.sent < len(self.entries) and round(self.entries[self.sent].at * NANOSECONDS_PER_SECOND) <= elapsed_ns
        ):
            self.sent += 1
        return list(self.entries[start : self.sent])
