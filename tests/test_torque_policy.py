"""The sim bridge's torque policy (sim_bridge/torque_policy.py) on its own: which torque a step
applies when torques come late, not at all, or too old, and when a lockstep step waits on. Plain values, no zenoh, no PyBullet: the
wheels are a list of torques and a brake flag, as :class:`~sim_bridge.simulator.SimulatedRobot`
keeps them; the events are the lines the log would say."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, Time, TimedDoubleSeq
from services.config import SimConfig, SimMode
from sim_bridge.latency import TorqueLatency
from sim_bridge.progress import RunProgress
from sim_bridge.torque_policy import TORQUE_COUNTERS, TorquePolicy, brake_steps

STEP_NS = 1_000_000
"""The default step, 0.001 s."""
LATENCY_NS = 30_000
"""What the fake clock says passes between a step's wheel angles and its torque."""


class Wheels:
    """Two wheels as the policy drives them: a torque or zero torque releases the brakes, as the
    simulated robot's do."""

    wheel_count = 2

    def __init__(self) -> None:
        self.torques: list[float] = [0.0, 0.0]
        self.braking = False

    def set_torques(self, torques: Sequence[float]) -> None:
        self.torques, self.braking = list(torques), False

    def set_zero_torques(self) -> None:
        self.torques, self.braking = [0.0, 0.0], False

    def brake(self) -> None:
        self.set_zero_torques()
        self.braking = True


@dataclass
class Events:
    said: list[tuple[str, int]] = field(default_factory=list)

    def waiting(self, tm_ns: int, waited_s: float) -> None:
        self.said.append(("waiting", tm_ns))

    def silent(self) -> None:
        self.said.append(("silent", 0))

    def answering(self) -> None:
        self.said.append(("answering", 0))

    def braking(self) -> None:
        self.said.append(("braking", 0))

    def kinds(self) -> list[str]:
        return [kind for kind, _ in self.said]


@dataclass
class Rig:
    policy: TorquePolicy
    wheels: Wheels
    events: Events
    counters: dict[str, int]
    progress: RunProgress
    latency: TorqueLatency
    clock_ns: list[int]

    def torque(self, tm_ns: int, left: float = 1.0, right: float = 2.0) -> None:
        """A ``motor/torque`` stamped ``tm_ns`` arrives, ``LATENCY_NS`` after its wheel angles."""
        self.clock_ns[0] = tm_ns + LATENCY_NS
        self.policy.on_torque(TimedDoubleSeq(Time.from_nanoseconds(tm_ns), [left, right]), None)

    def publish(self, tm_ns: int) -> None:
        """The step at ``tm_ns`` publishes its wheel angles."""
        self.progress.published_ns = tm_ns
        self.latency.published(tm_ns, tm_ns)

    def lockstep_step(self, step_index: int, answered: bool, final: bool = False, intervals: int = 0) -> None:
        """One lockstep step with a motor alive: ``intervals`` times ``sim.lockstep_timeout`` pass,
        then its torque comes; or, the motor silent, its one real-time period runs out."""
        tm_ns = step_index * STEP_NS
        self.publish(tm_ns)
        policy = self.policy
        policy.begin_wait(tm_ns)
        for interval in range(1, intervals + 1):
            policy.still_waiting(tm_ns, interval * SimConfig().lockstep_timeout)
        if answered:
            self.torque(tm_ns)
        if not policy.settled():
            assert policy.silent, "only a silent motor control's wait runs out: an answering one's lasts while it lives"
            policy.silent_wait_ran_out(final)
        policy.end_wait(step_index, final)


def rig(mode: SimMode = SimMode.LOCKSTEP, *, motor_alive: bool = True, **sim: float | None) -> Rig:
    wheels, events, progress = Wheels(), Events(), RunProgress()
    counters = dict.fromkeys(TORQUE_COUNTERS, 0)
    latency = TorqueLatency(STEP_NS)
    clock_ns = [0]
    policy = TorquePolicy(
        wheels,
        SimConfig(mode=mode, **sim),
        STEP_NS,
        progress=progress,
        counters=counters,
        latency=latency,
        events=events,
        now_ns=lambda: clock_ns[0],
    )
    policy.set_motor_alive(motor_alive)
    return Rig(policy, wheels, events, counters, progress, latency, clock_ns)


def joined_rig(**sim: float | None) -> Rig:
    """A lockstep rig whose motor control came after the first step: silent until it answers."""
    r = rig(motor_alive=False, **sim)
    r.progress.started = True
    r.policy.set_motor_alive(True)
    return r


# --- lockstep ---


def test_lockstep_applies_the_torque_stamped_with_the_awaited_step_and_counts_it():
    r = rig()
    r.policy.begin_wait(5 * STEP_NS)
    r.torque(5 * STEP_NS, 0.5, -0.5)
    assert r.policy.settled()
    r.policy.end_wait(5, final=False)
    assert r.wheels.torques == [0.5, -0.5]
    assert r.counters["torques_applied"] == 1 and r.policy.torque_step == 5


def test_lockstep_ignores_a_torque_of_another_step_as_stale():
    r = rig()
    r.policy.begin_wait(5 * STEP_NS)
    r.torque(4 * STEP_NS, 0.5, -0.5)
    assert not r.policy.settled()
    assert r.wheels.torques == [0.0, 0.0] and r.counters["stale_torques"] == 1


def test_lockstep_ignores_a_second_torque_for_the_same_step_as_stale():
    r = rig()
    r.policy.begin_wait(STEP_NS)
    r.torque(STEP_NS, 0.5, 0.5)
    r.torque(STEP_NS, 9.0, 9.0)
    assert r.wheels.torques == [0.5, 0.5] and r.counters["stale_torques"] == 1


def test_lockstep_counts_a_torque_outside_any_wait_as_stale():
    r = rig()
    r.torque(0)
    assert r.counters["stale_torques"] == 1 and r.wheels.torques == [0.0, 0.0]


def test_the_wait_is_settled_without_a_motor_and_unsettled_with_one_until_it_answers():
    r = rig(motor_alive=False)
    r.policy.begin_wait(0)
    assert r.policy.settled()
    r.policy.set_motor_alive(True)
    assert not r.policy.settled()


def test_a_torque_with_another_number_of_wheels_is_bad_input_and_changes_nothing():
    r = rig()
    r.policy.begin_wait(0)
    with pytest.raises(BadInput, match="3 torques, expected 2"):
        r.policy.on_torque(TimedDoubleSeq(Time.from_nanoseconds(0), [1.0, 2.0, 3.0]), None)
    assert not r.policy.answered and r.wheels.torques == [0.0, 0.0]


def test_a_wait_past_the_timeout_is_said_each_interval_and_counted_once_per_step_and_its_torque_applied():
    r = rig()
    r.lockstep_step(1, answered=True, intervals=3)
    assert r.wheels.torques == [1.0, 2.0] and r.counters["torques_applied"] == 1
    assert r.counters["long_waits"] == 1 and r.events.said == [("waiting", STEP_NS)] * 3
    r.lockstep_step(2, answered=True)
    r.lockstep_step(3, answered=True, intervals=1)
    assert r.counters["long_waits"] == 2 and r.counters["missing_torques"] == 0


def test_a_motor_control_there_before_the_first_step_is_waited_for_from_it():
    r = rig()
    assert r.policy.motor_alive and not r.policy.silent and r.events.said == []


def test_a_motor_control_that_comes_after_the_first_step_is_silent_its_wait_one_real_time_period():
    r = joined_rig(step=0.001, realtime_factor=0.5)
    assert r.policy.silent and r.policy.silent_wait_s == pytest.approx(0.002)
    assert r.events.kinds() == ["silent"]


def test_realtime_knows_no_silent_motor_control():
    r = rig(SimMode.REALTIME, motor_alive=False)
    r.progress.started = True
    r.policy.set_motor_alive(True)
    assert not r.policy.silent and r.events.said == []


def test_a_silent_motors_unanswered_step_counts_as_missing():
    r = joined_rig()
    r.lockstep_step(1, answered=False)
    assert r.policy.silent and r.counters["missing_torques"] == 1 and r.counters["long_waits"] == 0


def test_only_a_silent_motors_answer_to_the_step_waited_for_ends_its_silence_a_stale_one_does_not():
    r = joined_rig()
    r.lockstep_step(1, answered=False)
    r.policy.begin_wait(2 * STEP_NS)
    r.torque(STEP_NS)
    assert r.policy.silent and r.counters["stale_torques"] == 1, "it may still hold a step for an output it missed"
    r.torque(2 * STEP_NS)
    assert not r.policy.silent and r.policy.settled() and r.events.kinds()[-1] == "answering"


def test_a_motor_that_goes_while_silent_is_no_longer_silent_and_not_said_to_answer():
    r = joined_rig()
    r.lockstep_step(1, answered=False)
    r.policy.set_motor_alive(False)
    assert not r.policy.silent and "answering" not in r.events.kinds()


def test_a_motor_that_comes_back_after_the_first_step_is_silent_again():
    r = joined_rig()
    r.lockstep_step(1, answered=True)
    r.policy.set_motor_alive(False)
    r.policy.set_motor_alive(True)
    assert r.policy.silent and r.events.kinds() == ["silent", "answering", "silent"]


def test_the_final_state_counts_neither_its_torque_nor_a_missing_one():
    r = rig()
    r.lockstep_step(7, answered=True, final=True)
    assert r.policy.answered and r.counters["torques_applied"] == 0
    r = joined_rig()
    r.lockstep_step(1, answered=False)
    r.lockstep_step(2, answered=False, final=True)
    assert r.counters["missing_torques"] == 1 and not r.wheels.braking


def test_a_step_that_waited_for_no_motor_counts_its_torque_missing_unless_one_came_or_it_is_final():
    r = rig()
    r.policy.begin_wait(STEP_NS)
    r.policy.not_awaited(final=False)
    assert r.counters["missing_torques"] == 1
    r.policy.begin_wait(2 * STEP_NS)
    r.torque(2 * STEP_NS)
    r.policy.not_awaited(final=False)
    r.policy.begin_wait(3 * STEP_NS)
    r.policy.not_awaited(final=True)
    assert r.counters["missing_torques"] == 1


def test_the_latency_of_each_answered_step_is_timed_by_the_injected_clock():
    r = rig()
    r.lockstep_step(1, answered=True)
    r.lockstep_step(2, answered=True)
    assert r.latency.samples == 2 and r.latency.max_ns == LATENCY_NS


# --- the brakes ---


def test_steps_without_torque_get_zero_torque_until_brake_after_then_the_brakes_said_once():
    r = rig(motor_alive=False, brake_after=0.003)
    for step in range(5):
        r.policy.begin_wait(step * STEP_NS)
        r.policy.end_wait(step, final=False)
        assert r.wheels.braking == (step >= 3), step
    assert r.counters["braked_steps"] == 2 and r.events.kinds() == ["braking"]


def test_without_brake_after_the_wheels_never_brake():
    r = rig(motor_alive=False, brake_after=None)
    for step in range(10_000):
        r.policy.end_wait(step, final=False)
    assert not r.wheels.braking and r.counters["braked_steps"] == 0


def test_a_torque_after_braking_releases_the_brakes_and_restarts_the_count():
    r = joined_rig(brake_after=0.002)
    for step in range(3):
        r.lockstep_step(step, answered=False)
    assert r.wheels.braking
    r.lockstep_step(3, answered=True)
    assert not r.wheels.braking and r.policy.torque_step == 3
    r.policy.set_motor_alive(False)
    r.lockstep_step(4, answered=False)
    assert not r.wheels.braking


def test_brake_steps_rounds_brake_after_to_whole_steps_and_is_at_least_one():
    assert brake_steps(0.5, STEP_NS) == 500
    assert brake_steps(0.0014, STEP_NS) == 1
    assert brake_steps(1e-9, STEP_NS) == 1
    assert brake_steps(None, STEP_NS) is None


@settings(max_examples=200)
@given(st.floats(1e-6, 100.0), st.integers(1, 100_000_000))
def test_brake_steps_is_the_nearest_whole_number_of_steps_and_never_zero(brake_after: float, step_ns: int):
    steps = brake_steps(brake_after, step_ns)
    assert steps is not None and steps >= 1
    exact = brake_after * NANOSECONDS_PER_SECOND / step_ns
    assert steps == 1 or abs(steps - exact) <= 0.5


# --- realtime ---


def test_realtime_applies_the_newest_torque_within_its_maximum_age():
    r = rig(SimMode.REALTIME, torque_max_age=0.01)
    r.publish(3 * STEP_NS)
    r.torque(2 * STEP_NS, 0.5, 0.5)
    r.policy.realtime(3 * STEP_NS, 3)
    assert r.wheels.torques == [0.5, 0.5] and r.counters["torques_applied"] == 1 and r.policy.torque_step == 3
    assert r.counters["realtime_late_steps"] == 1, "the step's own torque had not come"


def test_realtime_applies_no_torque_older_than_its_maximum_age_and_counts_it_missing():
    r = rig(SimMode.REALTIME, torque_max_age=0.002)
    r.publish(0)
    r.torque(0, 0.5, 0.5)
    r.policy.realtime(3 * STEP_NS, 3)
    assert r.wheels.torques == [0.0, 0.0] and r.counters["missing_torques"] == 1


def test_realtime_keeps_the_newest_torque_whatever_order_they_arrive_in():
    r = rig(SimMode.REALTIME)
    r.publish(2 * STEP_NS)
    r.torque(2 * STEP_NS, 0.2, 0.2)
    r.torque(STEP_NS, 0.1, 0.1)
    r.policy.realtime(2 * STEP_NS, 2)
    assert r.wheels.torques == [0.2, 0.2] and r.counters["realtime_late_steps"] == 0


def test_realtime_torque_stamped_after_the_latest_step_is_bad_input_from_the_future():
    r = rig(SimMode.REALTIME)
    r.publish(STEP_NS)
    with pytest.raises(BadInput, match="from the future"):
        r.torque(2 * STEP_NS)
    assert r.policy.newest_torque is None


def test_realtime_without_any_torque_applies_zero_torque():
    r = rig(SimMode.REALTIME, brake_after=None)
    r.wheels.set_torques([1.0, 1.0])
    r.policy.realtime(0, 0)
    assert r.wheels.torques == [0.0, 0.0] and r.counters["missing_torques"] == 1


# --- properties ---


@settings(max_examples=200)
@given(st.integers(0, 20), st.lists(st.integers(0, 20), max_size=12))
def test_a_lockstep_wait_applies_exactly_the_first_torque_of_its_step_and_counts_every_other_stale(
    awaited: int, stamps: list[int]
):
    r = rig()
    r.policy.begin_wait(awaited * STEP_NS)
    for index, stamp in enumerate(stamps):
        r.torque(stamp * STEP_NS, float(index), float(stamp))
    applied = awaited in stamps
    assert r.policy.answered == applied
    assert r.counters["stale_torques"] == len(stamps) - applied
    assert r.wheels.torques == ([float(stamps.index(awaited)), float(awaited)] if applied else [0.0, 0.0])


@settings(max_examples=200)
@given(st.integers(0, 20), st.lists(st.integers(0, 4), max_size=40))
def test_a_joined_motor_is_silent_until_its_first_torque_then_every_step_waits_for_its_own(
    unanswered: int, intervals: list[int]
):
    """Silent: ``unanswered`` steps go by, each missing; then each step waits, ``intervals`` times
    ``sim.lockstep_timeout`` (said each time, counted once per step), for the torque it applies."""
    r = joined_rig()
    for step in range(unanswered):
        r.lockstep_step(step, answered=False)
        assert r.policy.silent
    for offset, waited in enumerate(intervals):
        r.lockstep_step(unanswered + offset, answered=True, intervals=waited)
        assert not r.policy.silent
    assert r.counters["missing_torques"] == unanswered
    assert r.counters["torques_applied"] == len(intervals)
    assert r.counters["long_waits"] == sum(1 for waited in intervals if waited)
    assert r.events.kinds().count("waiting") == sum(intervals)


@settings(max_examples=200)
@given(st.lists(st.booleans(), max_size=80), st.integers(1, 10))
def test_the_wheels_brake_at_each_step_brake_after_or_more_past_the_last_torque(answers: list[bool], brake: int):
    r = rig(brake_after=brake * STEP_NS / NANOSECONDS_PER_SECOND)
    last_torque, braked = 0, 0
    for step, answered in enumerate(answers):
        r.policy.set_motor_alive(answered)  # a step without torque: no motor control alive
        r.lockstep_step(step, answered)
        if answered:
            last_torque = step
        should_brake = not answered and step - last_torque >= brake
        braked += should_brake
        assert r.wheels.braking == should_brake, step
    assert r.counters["braked_steps"] == braked


@settings(max_examples=200)
@given(st.integers(0, 50), st.integers(0, 50), st.integers(1, 50))
def test_realtime_applies_the_newest_torque_if_and_only_if_it_is_no_older_than_torque_max_age(
    newest: int, age: int, max_age: int
):
    r = rig(SimMode.REALTIME, torque_max_age=max_age * STEP_NS / NANOSECONDS_PER_SECOND, brake_after=None)
    r.publish(newest * STEP_NS)
    r.torque(newest * STEP_NS, 0.3, 0.3)
    now = newest + age
    r.policy.realtime(now * STEP_NS, now)
    assert (r.wheels.torques == [0.3, 0.3]) == (age <= max_age)
    assert r.counters["torques_applied"] + r.counters["missing_torques"] == 1
