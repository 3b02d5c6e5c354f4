"""The localization stub's core: fix schedule in simulation time, noise, theta wrap, bad input."""

from __future__ import annotations

import math
import statistics
import threading
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.clock.sim_time import PeriodicSchedule
from services.config import Config, InputConfig, LocalizationConfig
from services.localization.core import Localizer, Noise, resolve_seed
from services.planar import Pose, wrap_angle

MS = 1_000_000
S = 1_000_000_000


HORIZON_NS = round(InputConfig().stamp_horizon * S)


def localizer(
    rate: float = 1.0,
    noise: Noise = Noise(),
    seed: int = 1,
    initial: Pose = Pose(0.0, 0.0, 0.0),
):
    return Localizer(initial, rate, noise, np.random.default_rng(seed), InputConfig())


def sim_pose(k: int) -> list[float]:
    """A moving simulated pose, different at every sample."""
    return [0.001 * k, -0.002 * k, 0.05, wrap_angle(0.003 * k)]


def feed(loc: Localizer, stamps: list[int]):
    return [(k, fix) for k, stamp in enumerate(stamps) if (fix := loc.on_sim_pose(stamp, sim_pose(k))) is not None]


def test_fixes_come_at_exactly_the_configured_simulated_rate() -> None:
    start = 7 * S + 3 * MS
    stamps = [start + k * MS for k in range(10_001)]  # 10 simulated seconds at 1 kHz
    fixes = feed(localizer(rate=2.0), stamps)
    assert len(fixes) == 1 + 10 * 2
    grid = [round(7.5 * S) + i * 500 * MS for i in range(20)]
    assert [fix.stamp_ns for _k, fix in fixes] == [start, *grid], "the first, then the grid anchored at t = 0"


def test_the_initial_pose_comes_first_stamped_with_the_first_sample() -> None:
    loc = localizer(initial=Pose(1.5, -2.0, 0.25))
    first = loc.on_sim_pose(42 * MS, [9.0, 9.0, 0.0, 1.0])
    assert first is not None and first.initial
    assert (first.stamp_ns, first.pose) == (42 * MS, Pose(1.5, -2.0, 0.25))
    later = loc.on_sim_pose(42 * MS + S, [3.0, 4.0, 0.0, -1.0])
    assert later is not None and not later.initial
    assert later.pose == Pose(3.0, 4.0, -1.0)


def test_with_zero_noise_a_fix_is_exactly_the_latest_simulated_pose() -> None:
    stamps = [k * 7 * MS for k in range(3000)]
    for k, fix in feed(localizer(rate=5.0), stamps)[1:]:
        x, y, _z, theta = sim_pose(k)
        assert fix.pose == Pose(x, y, theta)


def test_a_fix_is_taken_by_the_first_sample_at_or_after_its_tick_when_samples_are_sparse() -> None:
    # Samples every 300 ms, fixes at 1 Hz: ticks at 1 s, 2 s, ... are taken at 1.2 s, 2.1 s, 3.0 s.
    fixes = feed(localizer(rate=1.0), [k * 300 * MS for k in range(11)])
    assert [fix.stamp_ns for _k, fix in fixes] == [0, 1200 * MS, 2100 * MS, 3000 * MS]


def test_a_gap_longer_than_a_period_yields_one_fix_not_a_burst() -> None:
    loc = localizer(rate=10.0)
    loc.on_sim_pose(0, sim_pose(0))
    assert loc.on_sim_pose(550 * MS, sim_pose(1)) is not None  # five ticks missed, one fix
    assert loc.on_sim_pose(580 * MS, sim_pose(2)) is None
    assert loc.on_sim_pose(600 * MS, sim_pose(3)) is not None


@given(
    rate=st.floats(min_value=0.5, max_value=200.0),
    start=st.integers(min_value=0, max_value=10**12),
    gaps=st.lists(st.integers(min_value=1, max_value=400 * MS), min_size=1, max_size=200),
)
def test_schedule_takes_a_tick_exactly_when_one_falls_since_the_previous_stamp(rate, start, gaps) -> None:
    schedule = PeriodicSchedule(rate, start)
    ticks = [start + round(k * S / rate) for k in range(1 + math.ceil(sum(gaps) * rate / S) + 1)]
    assert schedule.due(start)
    previous = start
    for gap in gaps:
        now = previous + gap
        expected = any(previous < tick <= now for tick in ticks)
        assert schedule.due(now) == expected
        previous = now


def test_noise_has_the_configured_mean_and_standard_deviation() -> None:
    sigma = Noise(x=0.1, y=0.2, theta=0.05)
    loc = localizer(rate=1000.0, noise=sigma, seed=2024)
    errors: list[tuple[float, float, float]] = []
    for k in range(4001):
        x, y, z, theta = 1.0, -3.0, 0.0, 0.5
        fix = loc.on_sim_pose(k * MS, [x, y, z, theta])
        if fix is not None and not fix.initial:
            errors.append((fix.pose.x - x, fix.pose.y - y, fix.pose.theta - theta))
    assert len(errors) == 4000
    for axis, sigma_axis in zip(zip(*errors), (sigma.x, sigma.y, sigma.theta)):
        # mean within 4 standard errors, sample σ within 5 % (about 4.5 standard errors of σ for n = 4000)
        assert abs(statistics.fmean(axis)) < 4 * sigma_axis / math.sqrt(len(axis))
        assert statistics.stdev(axis) == pytest.approx(sigma_axis, rel=0.05)
    correlation = np.corrcoef(np.array(errors).T)
    assert np.all(np.abs(correlation - np.eye(3)) < 0.06), "axes must be independent"


def test_noisy_theta_is_wrapped_into_minus_pi_pi() -> None:
    loc = localizer(rate=1000.0, noise=Noise(theta=0.3), seed=5)
    thetas = [fix.pose.theta for k in range(2001) if (fix := loc.on_sim_pose(k * MS, [0, 0, 0, math.pi])) is not None]
    assert all(-math.pi < theta <= math.pi for theta in thetas)
    assert any(theta < 0 for theta in thetas) and any(theta > 0 for theta in thetas), "noise crossed ±π both ways"


def test_the_same_seed_repeats_the_noise_and_another_seed_does_not() -> None:
    stamps = [k * 100 * MS for k in range(50)]

    def run(seed: int) -> list[Pose]:
        return [fix.pose for _k, fix in feed(localizer(rate=10.0, noise=Noise(0.1, 0.1, 0.1), seed=seed), stamps)]

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_from_config_uses_every_localization_field() -> None:
    localization = LocalizationConfig(
        initial_x=1.0, initial_y=2.0, initial_theta=4.0, rate=4.0, noise_x=0.5, noise_y=0.25
    )
    loc = Localizer.from_config(Config(localization=localization), seed=9)
    assert loc.initial == Pose(1.0, 2.0, wrap_angle(4.0))
    assert (loc.rate_hz, loc.noise) == (4.0, Noise(0.5, 0.25, 0.0))


def test_resolve_seed_keeps_a_configured_seed_and_draws_a_reusable_one_otherwise() -> None:
    assert resolve_seed(17) == 17
    drawn = resolve_seed(None)
    assert 0 <= drawn < 2**63
    np.random.default_rng(drawn)  # a drawn seed is a valid seed


def test_a_wrong_length_is_bad_input_and_changes_nothing() -> None:
    loc = localizer()
    with pytest.raises(BadInput, match="expected 4 values"):
        loc.on_sim_pose(0, [1.0, 2.0, 3.0])
    assert (loc.fixes, loc.last_sim_pose, loc.started) == (0, None, False)
    assert loc.on_sim_pose(0, sim_pose(0)) is not None


def test_a_stamp_not_after_the_previous_one_is_bad_input() -> None:
    loc = localizer(rate=1.0)
    loc.on_sim_pose(S, sim_pose(0))
    for stamp in (S, S - 1):
        with pytest.raises(BadInput, match="<= 0"):
            loc.on_sim_pose(stamp, sim_pose(1))
    assert loc.last_sim_pose == Pose(*sim_pose(0)[:2], sim_pose(0)[3])
    assert loc.on_sim_pose(2 * S, sim_pose(2)) is not None


def test_nothing_starts_until_may_start() -> None:
    loc = localizer(rate=1.0, initial=Pose(5.0, 0.0, 0.0))
    assert loc.on_sim_pose(0, sim_pose(0), may_start=False) is None
    assert loc.last_sim_pose is not None and not loc.started
    assert loc.on_sim_pose(S // 2, sim_pose(1), may_start=False) is None
    first = loc.on_sim_pose(S, sim_pose(2))
    assert first is not None and first.initial and first.stamp_ns == S
    assert loc.on_sim_pose(2 * S, sim_pose(3), may_start=False) is not None, "once started, the flag no longer matters"


def test_noise_rejects_negative_or_non_finite_sigmas() -> None:
    for bad in ({"x": -0.1}, {"y": math.inf}, {"theta": math.nan}):
        with pytest.raises(ValueError, match="noise"):
            Noise(**bad)


def test_after_a_restart_the_first_sample_takes_a_fix_at_once_and_anchors_the_grid() -> None:
    loc = localizer(rate=2.0, initial=Pose(5.0, 5.0, 0.0))
    fixes = feed(loc, [k * 100 * MS for k in range(31)])  # 3 s: the initial pose, then 6 fixes
    assert len(fixes) == 7 and loc.fixes == 7
    with pytest.raises(BadInput):
        loc.on_sim_pose(0, sim_pose(0))
    loc.restart.simulator_appeared()
    restart_ns = 30 * MS  # the new clock starts again, before the old one's last stamp
    first = loc.on_sim_pose(restart_ns, [1.0, 2.0, 0.0, 0.5])
    assert first is not None and not first.initial, "a fix of the simulated pose, not the initial pose again"
    assert (first.stamp_ns, first.pose) == (restart_ns, Pose(1.0, 2.0, 0.5))
    assert loc.time_base_restarts == 1
    later = feed(loc, [restart_ns + k * 100 * MS for k in range(1, 11)])
    assert [fix.stamp_ns for _k, fix in later] == [restart_ns + 500 * MS, restart_ns + 1000 * MS]
    assert loc.fixes == 10


def test_a_simulator_appearing_with_a_clock_that_goes_on_changes_nothing() -> None:
    appeared, reference = localizer(rate=2.0), localizer(rate=2.0)
    stamps = [k * 100 * MS for k in range(21)]

    def fix_stamps(loc: Localizer, taken: list[int]) -> list[int]:
        return [fix.stamp_ns for stamp in taken if (fix := loc.on_sim_pose(stamp, sim_pose(0))) is not None]

    before = fix_stamps(appeared, stamps[:7])
    appeared.restart.simulator_appeared()
    expected = [0, 500 * MS, 1 * S, 1500 * MS, 2 * S]
    assert before + fix_stamps(appeared, stamps[7:]) == fix_stamps(reference, stamps) == expected
    assert appeared.time_base_restarts == 0


def test_a_restart_before_the_schedule_starts_keeps_the_initial_pose_first() -> None:
    loc = localizer(initial=Pose(5.0, 0.0, 0.0))
    assert loc.on_sim_pose(9 * S, sim_pose(0), may_start=False) is None
    loc.restart.simulator_appeared()
    first = loc.on_sim_pose(0, sim_pose(1))
    assert first is not None and first.initial and first.stamp_ns == 0
    assert loc.time_base_restarts == 1


def test_a_forged_far_future_sim_pose_does_not_freeze_the_fixes() -> None:
    loc = localizer(rate=1.0)
    loc.on_sim_pose(0, sim_pose(0))
    with pytest.raises(BadInput, match="ahead"):
        loc.on_sim_pose(10**29 * S, sim_pose(1))
    assert loc.on_sim_pose(S, sim_pose(2)) is not None


def test_an_implausible_position_is_bad_input() -> None:
    loc = localizer()
    with pytest.raises(BadInput, match="max_coordinate"):
        loc.on_sim_pose(0, [1e308, 0.0, 0.0, 0.0])
    assert loc.last_sim_pose is None


def test_started_while_the_simulator_runs_the_first_fix_is_the_simulated_pose() -> None:
    loc = localizer(rate=2.0, initial=Pose(0.0, 0.0, 0.0))
    first = loc.on_sim_pose(500 * MS + 1, [1.0, 1.0, 0.05, 1.5])  # just past one fix period
    assert first is not None and not first.initial and loc.first_fix_from_sim_pose
    assert first.pose == Pose(1.0, 1.0, 1.5)


def test_at_the_start_of_a_run_the_first_fix_is_the_initial_pose() -> None:
    loc = localizer(rate=2.0, initial=Pose(2.0, 3.0, 0.5))
    first = loc.on_sim_pose(500 * MS, [1.0, 1.0, 0.05, 1.5])  # within one fix period of time 0
    assert first is not None and first.initial and loc.first_fix_from_sim_pose is False
    assert first.pose == Pose(2.0, 3.0, 0.5)


def _returns_within(call, seconds: float = 2.0):
    result = []
    thread = threading.Thread(target=lambda: result.append(call()), daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"did not return within {seconds} s"
    return result[0]


@given(
    rate=st.floats(min_value=1e-3, max_value=1e4),
    start=st.integers(min_value=0, max_value=10**40),
    now=st.integers(min_value=0, max_value=10**45),
)
def test_schedule_due_returns_at_once_for_any_stamp(rate, start, now) -> None:
    schedule = PeriodicSchedule(rate, start)
    due = _returns_within(lambda: schedule.due(start + now))
    assert due is True
    assert schedule.next_ns > start + now
    assert schedule.index == 1 or schedule._tick_ns(schedule.index - 1) <= start + now


@given(
    rate=st.floats(min_value=1e-3, max_value=1e9, allow_nan=False, allow_infinity=False),
    start=st.integers(min_value=0, max_value=10**12),
    index=st.integers(min_value=0, max_value=10**15),
)
def test_a_tick_is_the_exact_rational_grid_rounded_as_round_does(rate, start, index) -> None:
    period = Fraction(S) / Fraction(rate)
    assert PeriodicSchedule(rate, start)._tick_ns(index) == start + round(index * period)


def test_a_tick_exactly_half_way_rounds_to_even() -> None:
    schedule = PeriodicSchedule(8e8, 0)  # a period of 1.25 ns: every other tick falls on a half
    assert [schedule._tick_ns(k) for k in range(7)] == [0, 1, 2, 4, 5, 6, 8]
    assert [schedule._tick_ns(k) for k in range(7)] == [round(k * Fraction(5, 4)) for k in range(7)]


def test_a_stamp_on_a_tick_that_rounds_down_onto_it_takes_that_tick() -> None:
    """1e9 / 1.9 as a float's exact value puts tick 475 a hair past 250 s, and rounding puts it on it."""
    schedule = PeriodicSchedule(1.9, 0)
    assert schedule.due(250 * 10**9)
    assert schedule.index == 476 and schedule.next_ns > 250 * 10**9
    assert not schedule.due(250 * 10**9 + 1), "one stamp later is not another tick"


def test_the_measured_hang_returns() -> None:
    assert _returns_within(lambda: PeriodicSchedule(50, 0).due(10**38)) is True
