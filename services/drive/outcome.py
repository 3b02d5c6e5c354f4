"""How a scenario ends, and when the drive gives it up (pure, no zenoh): docs/drive.md, "Outcomes".

A scenario ends **completed** when its last segment is done. The drive gives it up, as a
navigation stack aborts a goal, when it can no longer complete it:

- **aborted**: the motor has stayed latched stopped (a bump, an emergency stop) for
  ``drive.give_up_after_stop`` simulated seconds: nothing the drive commands can move the robot
  until someone clears the stop; or the motor's collision monitor has held the robot (``motor/state``'s
  ``held_by``: an obstacle in the stop zone, or no recent scan) continuously for as long: the way
  ahead stays blocked;
- **timed_out**: one pass of the scenario has lasted longer than its time limit (the scenario
  file's ``time_limit``, else ``drive.time_limit_factor`` × its planned duration +
  ``drive.time_limit_margin``).

Every outcome has an exit code, the drive's and ``invent up``'s: :data:`EXIT_CODES`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import DriveConfig
from services.drive.scenarios import Scenario, planned_duration
from services.exits import ExitStatus
from services.planar import Pose


class Outcome(StrEnum):
    COMPLETED = "completed"
    ABORTED = "aborted"
    TIMED_OUT = "timed_out"
    CANCELED = "canceled"

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self]


EXIT_CODES: dict[Outcome, int] = {
    Outcome.COMPLETED: ExitStatus.OK,
    Outcome.ABORTED: ExitStatus.ABORTED,
    Outcome.TIMED_OUT: ExitStatus.TIMED_OUT,
    Outcome.CANCELED: ExitStatus.CANCELED,
}
"""The exit code of ``invent drive`` and of ``invent up`` for each outcome (docs/protocol.md section 8.5)."""
OUTCOME_OF_EXIT_CODE: dict[int, Outcome] = {code: outcome for outcome, code in EXIT_CODES.items()}


def time_limit(scenario: Scenario, start: Pose, params: DriveConfig) -> float | None:
    """Simulated seconds one pass of ``scenario`` from ``start`` may last: the scenario's own
    ``time_limit``, else ``time_limit_factor`` × its planned duration + ``time_limit_margin``;
    None when neither limits it (``time_limit_factor`` none)."""
    if scenario.time_limit is not None:
        return scenario.time_limit
    if params.time_limit_factor is None:
        return None
    return params.time_limit_factor * planned_duration(scenario, start, params) + params.time_limit_margin


@dataclass(frozen=True)
class GiveUp:
    """Why the drive gives its scenario up."""

    outcome: Outcome
    reason: str


class GiveUpRule:
    """The drive's side: tell it what the motor's state and the bumps are, and ask at each tick."""

    def __init__(self, params: DriveConfig, limit_s: float | None) -> None:
        self._stop_ns = None if params.give_up_after_stop is None else _ns(params.give_up_after_stop)
        self.limit_s = limit_s
        self._limit_ns = None if limit_s is None else _ns(limit_s)
        self.stopped_since_ns: int | None = None
        """The simulation time from which the motor has been latched stopped; None while it is not."""
        self.stopped_by = ""
        self.last_bump: tuple[int, str] | None = None
        """(simulation time in ns, obstacle) of the latest bump the simulator reported."""
        self.stop_bump: tuple[int, str] | None = None
        """The bump that latched the current stop (a robot pushed back touches again while stopped)."""
        self.held_since_ns: int | None = None
        """The simulation time from which the collision monitor has held the robot; None while it does not."""
        self.held_by = ""

    @property
    def stopped_since_s(self) -> float | None:
        """:attr:`stopped_since_ns` in seconds (the status's ``motor_stopped_since_s``)."""
        return None if self.stopped_since_ns is None else self.stopped_since_ns / NANOSECONDS_PER_SECOND

    @property
    def held_since_s(self) -> float | None:
        """:attr:`held_since_ns` in seconds (the status's ``motor_held_since_s``)."""
        return None if self.held_since_ns is None else self.held_since_ns / NANOSECONDS_PER_SECOND

    def motor_state(self, state: str, stamp_ns: int, stopped_by: str, held_by: str = "") -> None:
        """The motor's state changed at ``stamp_ns`` (its wheel-angle time); ``held_by``: why its
        collision monitor holds the robot ("" while it does not). A hold whose cause changes goes on."""
        if not held_by:
            self.held_since_ns = None
        elif self.held_since_ns is None:
            self.held_since_ns = stamp_ns
        self.held_by = held_by
        if state != "stopped":
            self.stopped_since_ns, self.stop_bump = None, None
        elif self.stopped_since_ns is None:
            self.stopped_since_ns = stamp_ns
            self.stopped_by = stopped_by
            self._blame(self.last_bump)

    def restart(self, now_ns: int) -> None:
        """A new simulator's time base from ``now_ns``: a stop still latched counts from there (the
        motor keeps its latch across a simulator restart), the old time base's bumps are forgotten."""
        if self.stopped_since_ns is not None:
            self.stopped_since_ns = now_ns
        self.last_bump = self.stop_bump = None
        self.held_since_ns, self.held_by = None, ""  # the motor forgets its scans and its hold too

    def bump(self, obstacle: str, stamp_ns: int) -> None:
        self.last_bump = (stamp_ns, obstacle)
        self._blame(self.last_bump)

    def _blame(self, bump: tuple[int, str] | None) -> None:
        """Take ``bump`` as the stop's cause if the motor says a bump stopped it, none is blamed yet
        and the two are at most :data:`BUMP_NEAR_STOP_S` apart (either may arrive first, and the
        motor stamps its state with its latest wheel angles, which may be a step older than the
        contact)."""
        if (
            bump is not None
            and self.stop_bump is None
            and self.stopped_by == "bump"
            and self.stopped_since_ns is not None
            and abs(self.stopped_since_ns - bump[0]) <= _ns(BUMP_NEAR_STOP_S)
        ):
            self.stop_bump = bump

    def limit(self, limit_s: float | None) -> None:
        """From now on a pass (a goal) may last ``limit_s`` simulated seconds (None: no limit)."""
        self.limit_s = limit_s
        self._limit_ns = None if limit_s is None else _ns(limit_s)

    def check(self, now_ns: int, pass_elapsed_ns: int, from_ns: int | None = None, holds: bool = True) -> GiveUp | None:
        """Whether to give the scenario (or goal) up at ``now_ns``, ``pass_elapsed_ns`` into its
        current pass; a stop or hold counts from ``from_ns`` at the earliest (a goal's start);
        ``holds``: whether a hold gives up (false: a navigated goal, which recovers from holds itself)."""
        since_ns = _not_before(self._stop_start_ns(), from_ns)
        if self._stop_ns is not None and since_ns is not None and now_ns - since_ns >= self._stop_ns:
            return GiveUp(Outcome.ABORTED, self._stop_reason(since_ns, now_ns))
        held_ns = _not_before(self.held_since_ns, from_ns) if holds else None
        if self._stop_ns is not None and held_ns is not None and now_ns - held_ns >= self._stop_ns:
            held_s = (now_ns - held_ns) / NANOSECONDS_PER_SECOND
            return GiveUp(
                Outcome.ABORTED,
                f"held by the collision monitor for {held_s:.3f} s since t = "
                f"{held_ns / NANOSECONDS_PER_SECOND:.3f} s: {self.held_by}",
            )
        if self._limit_ns is not None and pass_elapsed_ns > self._limit_ns:
            return GiveUp(
                Outcome.TIMED_OUT,
                f"the scenario ran {pass_elapsed_ns / NANOSECONDS_PER_SECOND:.3f} s, past its time limit of "
                f"{self.limit_s:.3f} s",
            )
        return None

    def _stop_start_ns(self) -> int | None:
        """When the stop began: at the bump that caused it, a stamp of the simulation itself (in
        realtime the motor latches when the sim's call reaches it, which varies from run to run;
        in lockstep at the contact's step, its state stamped a step before the bump's)."""
        return self.stop_bump[0] if self.stop_bump is not None else self.stopped_since_ns

    def _stop_reason(self, since_ns: int, now_ns: int) -> str:
        held_s = (now_ns - since_ns) / NANOSECONDS_PER_SECOND
        bump = self.stop_bump
        if bump is not None:
            cause = f"bumped into {bump[1]!r} at t = {bump[0] / NANOSECONDS_PER_SECOND:.3f} s"
        else:
            cause = {
                "bump": "a bump",
                "gui": "an emergency stop (motor/gui/stop)",
                "state_file": "the stop latched in the motor's state file",
            }.get(self.stopped_by, "a stop")
        return f"{cause}: the motor latched stopped and stayed stopped for {held_s:.3f} s"


BUMP_NEAR_STOP_S = 0.5
"""How far in simulation time a bump may be from the stop it caused (in realtime the sim calls the
motor's ``motor/bump/stop`` without waiting, so the motor latches some steps after the contact)."""


def _not_before(stamp_ns: int | None, earliest_ns: int | None) -> int | None:
    if stamp_ns is None or earliest_ns is None:
        return stamp_ns
    return max(stamp_ns, earliest_ns)


def _ns(seconds: float) -> int:
    return round(seconds * NANOSECONDS_PER_SECOND)
