"""Status replies of each kind (schemas/status.py) with plausible values, for the tests of their
readers: each field given, none left to a default but the ones a test names."""

from __future__ import annotations

import msgspec

from schemas.drive_status import DriveNavigationStatus, DriveStatus
from schemas.status import (
    BadInputStatus,
    CollisionMonitorStatus,
    DroppedParticipant,
    LockstepHolds,
    MotorCounters,
    MotorStatus,
    PlanarPose,
    SensorsStatus,
    ServiceStatus,
    SimCounters,
    SimParameters,
    SimStatus,
    TorqueLatencyStatus,
    UserServiceStatus,
    Velocity,
)


class StateStatus(ServiceStatus, kw_only=True):
    """A service's status with a state as its only field of its own: a test's node's."""

    state: str


def service_status(bad: int = 0, internal: int = 0, dropped: int = 0) -> ServiceStatus:
    """Only the fields every service's status has."""
    return ServiceStatus(bad_input=BadInputStatus(total=bad), internal_errors=internal, dropped_events=dropped)


def sim_status(
    mode: str, steps: int, dropped_participants: tuple[DroppedParticipant, ...] = (), **counters: int
) -> SimStatus:
    return SimStatus(
        state="running",
        engine="kinematic",
        mode=mode,
        world="empty",
        sim_time_s=steps * 0.001,
        steps=steps,
        steps_per_second=1000.0,
        realtime_factor_achieved=1.0,
        parameters=SimParameters(
            step=0.001,
            observe_every=10,
            duration=None,
            lockstep_timeout=5.0,
            realtime_factor=1.0,
            torque_max_age=0.005,
            brake_after=None,
            max_wheel_torque=10.0,
        ),
        motor_alive=True,
        motor_silent=False,
        torques=[0.0, 0.0],
        pose=PlanarPose(0.0, 0.0, 0.0),
        counters=SimCounters(**counters),
        torque_latency=TorqueLatencyStatus(samples=0, p50_us=None, p99_us=None, max_us=None, bin_us=10.0, histogram=[]),
        late_fraction=0.0,
        lockstep_participants={},
        dropped_participants=list(dropped_participants),
        observed_steps=0,
        observed_rates={},
        drive_ended=False,
        braking=False,
        sensors=SensorsStatus(lidar=None, imu=None),
    )


def motor_status(bad: int = 0) -> MotorStatus:
    """A running motor without a collision monitor."""
    counters = MotorCounters(
        nonfinite_torques=0,
        wheel_angle_samples=0,
        body_pose_samples=0,
        target_velocity_samples=0,
        targets_ignored=0,
        command_timeouts=0,
    )
    return MotorStatus(
        bad_input=BadInputStatus(total=bad),
        state="running",
        output="torque",
        velocity_rate=None,
        target_angle="seed",
        gains={"p_gain_l": 5.0, "p_gain_r": 5.0, "d_gain_l": 2.0, "d_gain_r": 2.0},
        geometry={},
        offsets={},
        limits={},
        command_timeout=0.5,
        target=Velocity(0.0, 0.0),
        command=Velocity(0.0, 0.0),
        command_timed_out=False,
        counters=counters,
        collision_monitor=CollisionMonitorStatus(enabled=False),
        sim_alive=True,
        torques_published=0,
        wheel_velocities_published=0,
        lockstep_holds=LockstepHolds(held=0, released_unanswered=0),
        trace=None,
        state_file="motor.state",
        restored=None,
    )


def user_service_status(bad: int = 0, **own: object) -> bytes:
    """A user service's reply: the runtime's fields, and ``own`` merged over them."""
    runtime = UserServiceStatus(
        bad_input=BadInputStatus(total=bad), sim_alive=True, sim_time_s=None, lockstep=None, outputs={}, calls={}
    )
    return msgspec.json.encode({**msgspec.to_builtins(runtime), **own})


def drive_status(pose_wait_timeouts: int = 0, scans_late: int | None = None) -> DriveStatus:
    """A scenario's drive, or with ``scans_late`` a goal-mode drive that navigates."""
    return DriveStatus(
        state="running",
        mode="goals" if scans_late is not None else "scenario",
        rate_hz=20.0,
        commands_published=0,
        command=Velocity(0.0, 0.0),
        lockstep_participant=True,
        time_base_restarts=0,
        sim_alive=True,
        motor_stopped_since_s=None,
        motor_held_since_s=None,
        motor_held_by=None,
        outcome=None,
        odometry_alive=True,
        pose_wait_timeouts=pose_wait_timeouts,
        navigation=None
        if scans_late is None
        else DriveNavigationStatus(
            map=None,
            scans=scans_late,
            scans_dropped=0,
            scans_late=scans_late,
            scans_without_pose=0,
            costmap={},
            mapping=None,
        ),
    )
