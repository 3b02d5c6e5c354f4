"""Who a lockstep robot of the sim bridge waits for, on its own (sim_bridge/liveness.py): the
participants' tokens as they come and go, the drops the status names, the waits that go on past
``sim.lockstep_timeout``. Plain values, no zenoh: the tokens' changes are the calls the service
thread makes once the link's callbacks hand them over."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import pytest

from schemas.keys import Keys, Service
from schemas.messages import Time, TimedVelocity
from schemas.status import DroppedParticipant
from services.clock.lockstep import FINAL, TickBarrier
from services.clock.observation import ObservedSteps
from services.config import SimConfig
from services.runtime.logs import RateLimitedLog
from sim_bridge.latency import TorqueLatency
from sim_bridge.link import COUNTERS
from sim_bridge.liveness import Liveness
from sim_bridge.progress import RunProgress
from sim_bridge.torque_policy import TorquePolicy

KEYS = Keys()
MS = 1_000_000
DRIVE_TOKEN = KEYS.ticks(Service.DRIVE, 50.0)
LOCALIZATION_TOKEN = KEYS.ticks(Service.LOCALIZATION, 1.0)


class Wheels:
    wheel_count = 2
    braking = False

    def set_torques(self, torques: Sequence[float]) -> None: ...

    def set_wheel_velocities(self, targets: Sequence[float]) -> None: ...

    def set_zero_torques(self) -> None: ...

    def brake(self) -> None: ...


class Events:
    def waiting(self, tm_ns: int, waited_s: float) -> None: ...

    def silent(self) -> None: ...

    def answering(self) -> None: ...

    def braking(self) -> None: ...


def liveness(progress: RunProgress) -> Liveness:
    counters = dict.fromkeys(COUNTERS, 0)
    parameters = SimConfig()
    log = logging.getLogger("test.liveness")
    return Liveness(
        barrier=TickBarrier(),
        observation=ObservedSteps(parameters.observe_every),
        torque=TorquePolicy(
            Wheels(),
            parameters,
            MS,
            progress=progress,
            counters=counters,
            latency=TorqueLatency(MS),
            events=Events(),
            now_ns=lambda: 0,
        ),
        owed_changed=lambda: None,
        take_output=lambda service, output: None,
        progress=progress,
        counters=counters,
        parameters=parameters,
        log=log,
        warn=RateLimitedLog(log),
        prefix="",
    )


def started_with_the_drive_and_the_localization() -> Liveness:
    progress = RunProgress()
    robot = liveness(progress)
    robot.set_motor_alive(True)
    robot.participant_changed(DRIVE_TOKEN, alive=True)
    robot.participant_changed(LOCALIZATION_TOKEN, alive=True)
    progress.started = True
    progress.published_ns = 0
    return robot


def test_a_participant_gone_mid_wait_is_dropped_at_once_named_with_the_time_and_said(caplog):
    robot = started_with_the_drive_and_the_localization()
    robot.progress.published_ns = 1000 * MS
    assert sorted(robot.barrier.ticks(1000 * MS)) == [Service.DRIVE, Service.LOCALIZATION]
    with caplog.at_level(logging.INFO, "test.liveness"):
        robot.participant_changed(LOCALIZATION_TOKEN, alive=False)
    assert robot.barrier.missing() == [Service.DRIVE], "the wait in progress no longer waits for it"
    assert robot.dropped == [DroppedParticipant("localization", 1.0)]
    assert "localization gone at t = 1.000 s (its liveliness token): dropped" in caplog.text
    assert not robot.barrier.announced(Service.LOCALIZATION)


def test_a_participant_gone_after_its_last_output_or_once_the_steps_are_over_is_not_dropped():
    robot = started_with_the_drive_and_the_localization()
    robot.barrier.ticks(0)
    robot.on_output(
        Service.DRIVE, TimedVelocity(tm=Time.from_nanoseconds(0), id=[], vx=0.0, vy=0.0, w=0.0, error=[]), FINAL
    )
    robot.participant_changed(DRIVE_TOKEN, alive=False)
    assert robot.drive_ended and robot.dropped == []
    robot.steps_over = True
    robot.participant_changed(LOCALIZATION_TOKEN, alive=False)
    assert robot.dropped == []


def test_a_participant_gone_before_the_first_step_is_not_dropped():
    progress = RunProgress()
    robot = liveness(progress)
    robot.participant_changed(DRIVE_TOKEN, alive=True)
    robot.participant_changed(DRIVE_TOKEN, alive=False)
    assert robot.dropped == [] and not robot.barrier.announced(Service.DRIVE)


def test_a_tick_that_waits_on_is_said_each_interval_and_counted_once(caplog):
    robot = started_with_the_drive_and_the_localization()
    with caplog.at_level(logging.WARNING, "test.liveness"):
        robot.still_waiting([Service.DRIVE], 20 * MS, 0.5)
        robot.still_waiting([Service.DRIVE], 20 * MS, 1.0)
        robot.still_waiting([Service.DRIVE, Service.LOCALIZATION], 40 * MS, 0.5)
    assert robot.counters["long_waits"] == 2
    assert "still waiting for drive/target_velocity for t = 0.020 s after 0.5 s: its token alive" in caplog.text


@pytest.mark.parametrize("came_back", [False, True])
def test_a_robot_whose_motor_control_went_waits_for_no_participant_until_one_is_back(came_back: bool):
    robot = started_with_the_drive_and_the_localization()
    robot.set_motor_alive(False)
    assert robot.motor_lost
    if came_back:
        robot.set_motor_alive(True)
        assert not robot.motor_lost and robot.torque.silent, "back after the first step: silent until it answers"


def test_a_participant_whose_last_output_comes_after_its_token_had_ended_and_is_not_named():
    """The token and the last output travel separately: the token may come first."""
    robot = started_with_the_drive_and_the_localization()
    robot.progress.published_ns = 20 * MS
    robot.barrier.ticks(20 * MS)
    robot.participant_changed(DRIVE_TOKEN, alive=False)
    assert robot.dropped == [DroppedParticipant("drive", 0.02)] and robot.drive_ended
    last = TimedVelocity(tm=Time.from_nanoseconds(20 * MS), id=[], vx=0.0, vy=0.0, w=0.0, error=[])
    robot.on_output(Service.DRIVE, last, FINAL)
    assert robot.dropped == []
