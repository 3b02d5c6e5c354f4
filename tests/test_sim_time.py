"""Simulation time as every service follows it: a stamp stream's clock, and the one rule by which a
restarted simulator starts a new time base while a reconnected one costs nothing."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.clock.sim_time import GAP_ADOPTION_SAMPLES, ClockRestart, StampClock, StampGap
from services.config import InputConfig

S = 1_000_000_000
HORIZON_NS = round(InputConfig().stamp_horizon * S)


def test_without_an_appearance_nothing_restarts_and_nothing_is_deciding() -> None:
    restart = ClockRestart(HORIZON_NS)
    assert not restart.deciding
    assert restart.decide(0, 5 * S) is False, "time going back with no new simulator is bad input, not a restart"
    assert restart.restarts == 0


def test_a_reconnected_simulator_whose_clock_goes_on_restarts_nothing() -> None:
    restart = ClockRestart(HORIZON_NS)
    restart.simulator_appeared()
    assert restart.deciding
    assert restart.decide(5 * S + 1, 5 * S) is False
    assert not restart.deciding and restart.restarts == 0


@pytest.mark.parametrize("new_clock_ns", [0, 3 * S, 5 * S], ids=["zero", "earlier", "the same stamp"])
def test_a_restarted_simulator_whose_clock_is_not_after_the_last_stamp_starts_a_new_time_base(new_clock_ns) -> None:
    restart = ClockRestart(HORIZON_NS)
    restart.simulator_appeared()
    assert restart.decide(new_clock_ns, 5 * S) is True
    assert not restart.deciding and restart.restarts == 1
    assert restart.decide(0, new_clock_ns) is False, "one appearance, one decision"


def test_the_first_sample_ever_decides_without_a_restart() -> None:
    restart = ClockRestart(HORIZON_NS)
    restart.simulator_appeared()
    assert restart.decide(7 * S, None) is False and not restart.deciding


def test_a_stamp_beyond_the_horizon_decides_nothing() -> None:
    restart = ClockRestart(HORIZON_NS)
    restart.simulator_appeared()
    assert restart.decide(5 * S + HORIZON_NS + 1, 5 * S) is False
    assert restart.deciding, "a forged jump must not use up the appearance"
    assert restart.decide(0, 5 * S) is True


@given(
    last_ns=st.integers(0, 10**15),
    stamps=st.lists(st.integers(0, 2 * 10**15), min_size=1, max_size=8),
)
def test_one_appearance_makes_at_most_one_decision_and_it_restarts_only_a_clock_that_went_back(last_ns, stamps):
    restart = ClockRestart(HORIZON_NS)
    restart.simulator_appeared()
    decisions = []
    for stamp in stamps:
        was_deciding = restart.deciding
        restarted = restart.decide(stamp, last_ns)
        if was_deciding and not restart.deciding:
            decisions.append((stamp, restarted))
        else:
            assert restarted is False
    assert len(decisions) <= 1
    for stamp, restarted in decisions:
        assert restarted == (stamp <= last_ns)
    assert restart.restarts == sum(restarted for _stamp, restarted in decisions)


def test_stamp_clock_accepts_only_increasing_stamps() -> None:
    clock = StampClock(HORIZON_NS)
    clock.advance(5)
    clock.advance(6)
    with pytest.raises(BadInput):
        clock.advance(6)
    assert (clock.first_ns, clock.last_ns) == (5, 6)
    assert clock.restart.restarts == 0


def test_stamp_clock_restarts_only_after_a_simulator_appeared_and_the_stamp_goes_back() -> None:
    clock = StampClock(HORIZON_NS)
    clock.restart.simulator_appeared()
    assert clock.advance(5) is False, "the first stamp is no restart"
    clock.restart.simulator_appeared()
    assert clock.advance(9) is False, "a later stamp just goes on (a reconnection)"
    assert (clock.first_ns, clock.last_ns, clock.restart.restarts) == (5, 9, 0)
    with pytest.raises(BadInput):
        clock.advance(2)
    clock.restart.simulator_appeared()
    assert clock.advance(2) is True
    assert (clock.first_ns, clock.last_ns, clock.restart.restarts) == (2, 2, 1)
    with pytest.raises(BadInput):
        clock.advance(2)


def test_stamp_clock_after_a_forged_jump_still_takes_the_restart() -> None:
    clock = StampClock(HORIZON_NS)
    clock.advance(5 * S)
    clock.restart.simulator_appeared()
    with pytest.raises(BadInput, match="ahead of the time base"):
        clock.advance(100_000 * S)
    assert clock.restart.deciding, "a stamp beyond the horizon decides nothing"
    assert clock.advance(0) is True and (clock.first_ns, clock.last_ns) == (0, 0)


def test_stamp_clock_refuses_a_jump_beyond_the_horizon_and_keeps_its_time_base() -> None:
    clock = StampClock(HORIZON_NS)
    clock.advance(5 * S)
    for forged in (5 * S + HORIZON_NS + 1, 100_000 * S, 10**29 * S):
        with pytest.raises(BadInput, match="ahead of the time base"):
            clock.advance(forged)
    assert clock.last_ns == 5 * S
    assert clock.advance(5 * S + HORIZON_NS) is False, "a jump of exactly the horizon is fine"


def test_a_stream_back_after_a_gap_is_taken_at_its_fifth_steady_sample():
    gap = StampGap(horizon_ns=1_000, samples=GAP_ADOPTION_SAMPLES)
    assert gap.check(1_500, 1_000) is False
    back = [10_000 + 100 * index for index in range(GAP_ADOPTION_SAMPLES)]
    for stamp in back[:-1]:
        with pytest.raises(BadInput, match="ahead of the time base"):
            gap.check(stamp, 1_500)
    assert gap.check(back[-1], 1_500) is True and gap.gaps == 1


def test_one_forged_stamp_or_forgeries_among_a_live_stream_are_never_taken():
    gap = StampGap(horizon_ns=1_000, samples=3)
    last = 0
    for step in range(1, 50):
        with pytest.raises(BadInput):
            gap.check(10**12 + step, last)  # forged, steady among themselves
        assert gap.check(last + 100, last) is False  # the live stream, which the time base takes
        last += 100
    assert gap.gaps == 0


@given(st.lists(st.integers(min_value=1, max_value=5_000), min_size=1, max_size=40))
def test_a_run_is_taken_only_when_every_stamp_of_it_is_steady(steps):
    gap = StampGap(horizon_ns=1_000, samples=4)
    stamp, run = 100_000, 0
    for step in steps:
        stamp += step
        run = run + 1 if run > 0 and step <= 1_000 else 1
        try:
            taken = gap.check(stamp, 0)
        except BadInput:
            taken = False
        assert taken == (run >= 4)
        if taken:
            run = 0
