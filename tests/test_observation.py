"""Which steps the simulator marks observed (services/clock/observation.py), pure: every k-th step
and each tick of a rate a token asks for, so that whoever receives only the observed steps sees the
stamp of every one of its ticks."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.keys import Keys, Service
from schemas.tokens import parse_observes_key, parse_ticks_key
from services.clock.observation import ObservedSteps
from services.clock.sim_time import PeriodicSchedule

MS = 1_000_000
DRIVE_TOKEN = Keys("rh0").ticks(Service.DRIVE, 50.0)
ROS_TOKEN = Keys("rh0").observes(Service.ROS2, 100.0)


def _observed(steps: ObservedSteps, count: int, step_ns: int = MS, first: int = 0) -> list[int]:
    return [index for index in range(first, first + count) if steps.observed(index, index * step_ns)]


def test_observe_every_one_is_every_step_as_the_seeds():
    assert _observed(ObservedSteps(1), 50) == list(range(50))


def test_without_tokens_every_kth_step_is_observed_and_counted():
    steps = ObservedSteps(20)
    assert _observed(steps, 100) == [0, 20, 40, 60, 80]
    assert steps.count == 5


def test_a_token_adds_the_ticks_of_its_rate_until_it_goes():
    steps = ObservedSteps(1000)
    steps.add(ROS_TOKEN, 100.0)
    assert _observed(steps, 40) == [0, 10, 20, 30]
    assert steps.rates() == {ROS_TOKEN: 100.0}
    steps.remove(ROS_TOKEN)
    assert _observed(steps, 40, first=40) == [] and steps.rates() == {}


def test_a_token_seen_again_at_the_same_rate_keeps_its_grid():
    """Liveliness can report a token twice (history, then the live declaration): no extra step."""
    steps = ObservedSteps(1000)
    steps.add(DRIVE_TOKEN, 50.0)
    assert _observed(steps, 5) == [0]
    steps.add(DRIVE_TOKEN, 50.0)
    assert _observed(steps, 30, first=5) == [20]


def test_a_token_that_comes_mid_run_observes_the_ticks_of_the_grid_after_the_present():
    """Whoever joins late sees the same steps as if it had been there from the start."""
    steps = ObservedSteps(1000)
    assert _observed(steps, 7) == [0]
    steps.add(DRIVE_TOKEN, 50.0, now_ns=6 * MS)
    assert _observed(steps, 54, first=7) == [20, 40, 60]
    steps.add(ROS_TOKEN, 100.0, now_ns=60 * MS)
    assert _observed(steps, 39, first=61) == [70, 80, 90]


@pytest.mark.parametrize("every", [0, -3])
def test_observe_every_below_one_is_refused(every):
    with pytest.raises(ValueError, match="observe_every"):
        ObservedSteps(every)


@given(
    step_ns=st.integers(min_value=1_000, max_value=50 * MS),
    every=st.integers(min_value=1, max_value=500),
    rates=st.lists(st.floats(min_value=0.1, max_value=2000.0), min_size=1, max_size=3),
    count=st.integers(min_value=1, max_value=2000),
)
def test_a_consumer_fed_only_observed_steps_takes_the_same_ticks_as_one_fed_every_step(step_ns, every, rates, count):
    steps = ObservedSteps(every)
    for number, rate in enumerate(rates):
        steps.add(f"token-{number}", rate)
    every_step = {rate: PeriodicSchedule(rate, 0) for rate in rates}
    observed_only = {rate: PeriodicSchedule(rate, 0) for rate in rates}
    ticks_every: dict[float, list[int]] = {rate: [] for rate in rates}
    ticks_observed: dict[float, list[int]] = {rate: [] for rate in rates}
    for index in range(count):
        now_ns = index * step_ns
        for rate, schedule in every_step.items():
            if schedule.due(now_ns):
                ticks_every[rate].append(now_ns)
        if steps.observed(index, now_ns):
            for rate, schedule in observed_only.items():
                if schedule.due(now_ns):
                    ticks_observed[rate].append(now_ns)
        elif index % every == 0:
            pytest.fail(f"step {index} is a multiple of {every} and was not observed")
    assert ticks_observed == ticks_every


def test_the_observer_token_names_the_service_and_its_rate():
    keys = Keys("rh0")
    assert keys.observes(Service.ROS2, 50.0) == "invent/rh0/ros2/observes/50.0"
    assert parse_observes_key(keys.observes(Service.ROS2, 1 / 3)) == (Service.ROS2, 1 / 3)
    assert parse_observes_key(keys.ticks(Service.DRIVE, 50.0)) is None, "a participant's token is not an observer's"
    assert parse_ticks_key(keys.observes(Service.ROS2, 50.0)) is None
    for key in ("invent/rh0/ros2/observes/0.0", "invent/rh0/ros2/observes/inf", "invent/rh0/No-body/observes/1.0"):
        assert parse_observes_key(key) is None, key
