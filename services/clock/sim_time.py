"""Simulation time as the services see it: stamps in integer nanoseconds (pure, no zenoh).

The simulator stamps every sample with its own clock. Services that act "every so many
seconds" (localization fixes, drive commands) count those stamps, never the wall clock, so a
lockstep run faster than real time behaves exactly like a real-time one.
"""

from __future__ import annotations

import math
from fractions import Fraction

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND


def _seconds(nanoseconds: float) -> str:
    return f"{nanoseconds / NANOSECONDS_PER_SECOND:.6g} s"


def _next_stamp_refusal(stamp_ns: int, last_ns: int, horizon_ns: int) -> str | None:
    """Why ``stamp_ns`` cannot follow ``last_ns`` on a stream's own time base; None if it can."""
    return None if 0 < stamp_ns - last_ns <= horizon_ns else _refusal(stamp_ns, last_ns, horizon_ns)


def _refusal(stamp_ns: int, last_ns: int, horizon_ns: int) -> str:
    """Why ``stamp_ns``, which does not follow ``last_ns``, is refused."""
    if stamp_ns <= last_ns:
        return f"dt = {_seconds(stamp_ns - last_ns)} <= 0"
    return f"stamp jumps {_seconds(stamp_ns - last_ns)} ahead of the time base (horizon {_seconds(horizon_ns)})"


def check_next_stamp(stamp_ns: int, last_ns: int, horizon_ns: int) -> None:
    """The stamp policy of a stream's own time base: each stamp after the last, by at most the
    horizon. Raises BadInput otherwise; the caller then leaves its time base where it was, so one
    forged stamp far ahead cannot make every genuine sample after it look like time going back."""
    refusal = _next_stamp_refusal(stamp_ns, last_ns, horizon_ns)
    if refusal is not None:
        raise BadInput(refusal)


GAP_ADOPTION_SAMPLES = 5
"""A stream back after a gap longer than the horizon is taken again at its 5th steady sample."""


class StampGap:
    """:func:`check_next_stamp` for one stream, which also takes the stream back after a gap.

    A link down for a while loses the samples in between: the first one after it jumps further
    than the horizon, is refused, and leaves the time base where it was, so every later sample
    jumps further still and the stream would be refused for ever. So a run of
    :data:`GAP_ADOPTION_SAMPLES` stamps beyond the gap, each after the one before by at most the
    horizon, with no sample in between that the time base took, is the stream come back: the last
    of them is taken (:meth:`check` returns True). One forged stamp, or forgeries among a live
    stream's samples, never make such a run: each genuine sample the time base takes ends it."""

    def __init__(self, horizon_ns: int, samples: int = GAP_ADOPTION_SAMPLES) -> None:
        self.horizon_ns = horizon_ns
        self.samples = samples
        self.gaps = 0
        """Streams taken back after a gap."""
        self._run = 0
        self._run_last_ns = 0

    def check(self, stamp_ns: int, last_ns: int) -> bool:
        """False for a stamp the time base takes as usual; True for the stamp that takes the stream
        back after a gap (the caller takes it, with no Δt across the gap if it needs one); raises
        BadInput for the others, as :func:`check_next_stamp` does."""
        if 0 < stamp_ns - last_ns <= self.horizon_ns:  # no refusal to word: the case at every step
            self._run = 0
            return False
        if stamp_ns > last_ns:
            steady = self._run > 0 and 0 < stamp_ns - self._run_last_ns <= self.horizon_ns
            self._run = self._run + 1 if steady else 1
            self._run_last_ns = stamp_ns
            if self._run >= self.samples:
                self._run = 0
                self.gaps += 1
                return True
        raise BadInput(_refusal(stamp_ns, last_ns, self.horizon_ns))


def check_stamp_near(stamp_ns: int, reference_ns: int, horizon_ns: int, history_ns: float, what: str) -> None:
    """The stamp policy of an input checked against another time base (a target or a fix against
    the wheel-angle time): no further ahead than the horizon, no further back than the history
    the consumer keeps. Raises BadInput naming ``what`` otherwise."""
    if stamp_ns - reference_ns > horizon_ns:
        raise BadInput(
            f"{what} stamped {_seconds(stamp_ns - reference_ns)} ahead of the wheel-angle time "
            f"(horizon {_seconds(horizon_ns)})"
        )
    if reference_ns - stamp_ns > history_ns:
        raise BadInput(
            f"{what} stamped {_seconds(reference_ns - stamp_ns)} before the wheel-angle time, "
            f"older than the {_seconds(history_ns)} kept"
        )


class ClockRestart:
    """The one rule by which every service follows a restarted simulator (docs/protocol.md section 8.6).

    Zenoh shows the simulator's liveliness token appear both when a new simulator starts (its
    clock starts again, at 0) and when the same one reconnects (its clock goes on), and cannot
    tell the two apart; the stamps can. After :meth:`simulator_appeared`, the first sample of the
    simulator's clock *decides* (:meth:`decide`): a stamp not after the last one taken starts a
    new time base; a later one, within the horizon, means the clock goes on, and nothing
    restarts: a reconnect costs nothing. A stamp beyond the horizon decides nothing (it is bad
    input; a forged one must not make a genuine restart look like time going back).

    Until a sample decides, the service cannot judge an input stamped in the simulator's time
    (a target, a fix, a pose) against its old time base: ``deciding`` says so, and the service
    keeps such inputs until the sample that decides.
    """

    def __init__(self, horizon_ns: int) -> None:
        self.horizon_ns = horizon_ns
        self.deciding = False
        """True from the token's appearance until a sample of the clock decides."""
        self.restarts = 0
        """Time bases started again since the first."""

    def simulator_appeared(self) -> None:
        self.deciding = True

    def decide(self, stamp_ns: int, last_ns: int | None) -> bool:
        """Called with every clock sample's stamp before the service takes it (``last_ns``: the
        newest stamp it took, None before the first); True if the sample starts a new time base."""
        if not self.deciding or (last_ns is not None and stamp_ns - last_ns > self.horizon_ns):
            return False
        self.deciding = False
        restarted = last_ns is not None and stamp_ns <= last_ns
        self.restarts += restarted
        return restarted


class StampClock:
    """Accepts a stream of increasing stamps, each at most ``horizon_ns`` after the last
    (:func:`check_next_stamp`); anything else is bad input, but for the sample that starts a
    new time base after a simulator appeared (``restart``, a :class:`ClockRestart`) and the one
    that takes the stream back after a gap (``gap``, a :class:`StampGap`).
    """

    def __init__(self, horizon_ns: int) -> None:
        self.restart = ClockRestart(horizon_ns)
        self.gap = StampGap(horizon_ns)
        self.first_ns: int | None = None
        """The first stamp of the current time base."""
        self.last_ns: int | None = None

    @property
    def horizon_ns(self) -> int:
        return self.restart.horizon_ns

    def advance(self, stamp_ns: int) -> bool:
        """Take ``stamp_ns`` as the new time; True if it started a new time base.

        Raises BadInput (state unchanged) if the stamp is not later, or too far ahead, and does
        not start a new time base.
        """
        last_ns = self.last_ns
        restarted = self.restart.decide(stamp_ns, last_ns)
        if not restarted and last_ns is not None:
            self.gap.check(stamp_ns, last_ns)
        if restarted or self.first_ns is None:
            self.first_ns = stamp_ns
        self.last_ns = stamp_ns
        return restarted


class PeriodicSchedule:
    """Ticks at ``start_ns + round(k·1e9/rate)`` for k = 0, 1, 2, ...

    The grid is anchored at ``start_ns`` (no drift from rounding), and a tick is taken by the
    first stamp at or after it. After a gap longer than a period the missed ticks are skipped:
    one stamp takes at most one tick. The period is the exact rational value of 1e9/rate, and
    :meth:`due` finds the tick in integer arithmetic: it returns at once for any stamp. (Integer,
    not ``Fraction``, arithmetic: the simulator asks several schedules at every step, and a
    ``Fraction`` product and its rounding cost microseconds.)
    """

    def __init__(self, rate_hz: float, start_ns: int) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate must be finite and > 0, got {rate_hz}")
        self.rate_hz = rate_hz
        self.start_ns = start_ns
        period_ns = Fraction(NANOSECONDS_PER_SECOND) / Fraction(rate_hz)
        self._period_numerator, self._period_denominator = period_ns.numerator, period_ns.denominator
        self.index = 0
        """The index k of the next tick."""
        self.next_ns = start_ns
        """The stamp of the next tick (kept, not computed: :meth:`due` runs at every step)."""

    def _tick_ns(self, index: int) -> int:
        """``start_ns + round(index·period)``, rounding half to even as ``round`` does."""
        whole, remainder = divmod(index * self._period_numerator, self._period_denominator)
        twice = 2 * remainder
        if twice > self._period_denominator or (twice == self._period_denominator and whole % 2 == 1):
            whole += 1
        return self.start_ns + whole

    def due(self, now_ns: int) -> bool:
        """True when ``now_ns`` takes a tick; the schedule then moves past ``now_ns``."""
        if now_ns < self.next_ns:
            return False
        last_passed = (now_ns - self.start_ns) * self._period_denominator // self._period_numerator
        # rounding moves a tick by half a nanosecond at most: the floor is off by one at most either way
        if self._tick_ns(last_passed) > now_ns:
            last_passed -= 1
        elif self._tick_ns(last_passed + 1) <= now_ns:
            last_passed += 1
        self.index = max(last_passed, self.index) + 1
        self.next_ns = self._tick_ns(self.index)
        return True
