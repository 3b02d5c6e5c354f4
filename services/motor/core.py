"""MotorControl's pure core (docs/protocol.md section 4): no zenoh, plain floats, one control cycle per call.

:class:`MotorCore` turns each wheel-angle sample into one torque vector: wheel speeds from
the angle difference, target wheel speeds from the commanded body velocity, a target angle
(mode ``seed`` or ``integrated``), and a PD law per wheel. It also holds the Motor
interface's state machine (``idle``, ``running``, ``finished``, ``stopped``), the command
timeout, and the bounds on its input; the velocity, acceleration and jerk limits are a
:class:`~services.motor.speed_limiter.SpeedLimiter` per speed, the body pose's conversion a
:class:`~services.motor.sim_pose.SimPoseConverter`.

Per-sample work is a handful of float operations on locals: a benchmark runs this at
thousands of samples per second, so there is no numpy and no allocation beyond the torque list.
The collision monitor (:attr:`MotorCore.monitor`) adds a comparison per cycle: its geometry runs
only when a scan arrives or the command changes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import StrEnum

import msgspec

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, PDGains
from schemas.status import MotorCoreStatus, MotorCounters, Velocity
from services.clock.sim_time import StampGap, check_stamp_near
from services.config import CalibratedGeometry, InputConfig, MotorConfig, OdometryConfig, RobotConfig, TargetAngleMode
from services.motor.monitor import CollisionMonitor
from services.motor.sim_pose import SimPoseConverter
from services.motor.speed_limiter import SpeedLimiter, limits_status
from services.motor.wheel_velocity import WheelVelocityOutput
from services.planar import check_coordinates


class MotorState(StrEnum):
    IDLE = "idle"
    """No wheel angles or no target velocity seen yet: zero torque."""
    RUNNING = "running"
    """Torque control towards the target velocity."""
    FINISHED = "finished"
    """After ``finish``: zero torque (coasting) until ``start``."""
    STOPPED = "stopped"
    """After ``stop``, latched until ``clear``: torque control towards zero velocity (braking)."""


def check_target_velocity(vx: float, w: float, robot: RobotConfig, limits: InputConfig) -> None:
    """BadInput for a body velocity implying a wheel speed beyond ``input.max_wheel_speed`` (the
    robot's kinematics: ω_L,R = (vx ∓ b·w) / r_L,R). One within it but beyond the motor's velocity
    limits is plausible: the limits clamp it."""
    b = robot.half_axle
    wheel_speeds = ((vx - b * w) / robot.radius_of_left_wheel, (vx + b * w) / robot.radius_of_right_wheel)
    if not all(abs(speed) <= limits.max_wheel_speed for speed in wheel_speeds):
        raise BadInput(
            f"target (vx {vx:g} m/s, w {w:g} rad/s) implies wheel speeds {wheel_speeds[0]:g}, "
            f"{wheel_speeds[1]:g} rad/s, beyond input.max_wheel_speed = {limits.max_wheel_speed:g} rad/s"
        )


class MotorCore:
    """The motor controller of one robot: geometry, offsets and options locked at construction.

    Call :meth:`step` for every wheel-angle sample (it returns the torque vector),
    :meth:`set_target` for every target velocity, :meth:`sim_pose` for every body pose, and
    the Motor methods :meth:`set_pd_gain`, :meth:`start`, :meth:`finish`, :meth:`stop`,
    :meth:`clear`; :meth:`restart_time_base` when a restarted simulator's clock starts again. Bad input raises
    BadInput and changes nothing.

    After each :meth:`step`, ``cycle_state``, ``dq``, ``dq_ref`` and ``q_ref`` describe that
    cycle (None where the cycle computed no such value) for tracing.

    ``geometry`` is what turns a body velocity into wheel speeds: the robot description's
    calibrated lengths (``Config.geometry``, as the odometry integrates with); None, the robot's
    own radii and axle, uncalibrated.
    """

    def __init__(
        self,
        robot: RobotConfig,
        motor: MotorConfig,
        limits: InputConfig = InputConfig(),
        geometry: CalibratedGeometry | None = None,
    ) -> None:
        self.robot = robot
        self.motor = motor
        self.limits = limits
        self.geometry = geometry or CalibratedGeometry.of(robot, OdometryConfig())
        self._horizon_ns = limits.stamp_horizon_ns
        self._gap = StampGap(limits.stamp_horizon_ns)
        # A target older than the command timeout would be timed out anyway.
        self._target_history_ns = round((motor.command_timeout or limits.stamp_horizon) * NANOSECONDS_PER_SECOND)
        self._max_wheel_speed = limits.max_wheel_speed
        self.gains = PDGains(motor.p_gain_l, motor.p_gain_r, motor.d_gain_l, motor.d_gain_r)
        self._pose = SimPoseConverter.from_config(motor)
        self.velocity_output: WheelVelocityOutput | None = (
            WheelVelocityOutput(motor.velocity_rate, limits.max_wheel_speed) if motor.output == "velocity" else None
        )
        """``motor.output = "velocity"``: :meth:`step` returns wheel speed targets, not torques."""
        self.vx_limiter = SpeedLimiter.of(motor, "vx")
        self.w_limiter = SpeedLimiter.of(motor, "w")
        self._limited = self.vx_limiter.enabled or self.w_limiter.enabled
        self._integrated = motor.target_angle == TargetAngleMode.INTEGRATED
        self._timeout_ns = round(motor.command_timeout * NANOSECONDS_PER_SECOND)
        self._left, self._right = robot.left_wheel_id, robot.right_wheel_id
        self._min_length = max(self._left, self._right) + 1
        self._radius_l, self._radius_r, self._half_axle = self.geometry

        self._stamp_ns: int | None = None
        self.q: tuple[float, float] = (0.0, 0.0)

        self._have_target = False
        self.target: tuple[float, float] = (0.0, 0.0)
        """The last accepted target (vx, w)."""
        self._target_stamp_ns: int | None = None
        self._deferred_target: tuple[int, float, float] | None = None
        """A target stamped after the last wheel sample: (stamp, vx, w), applied from the first
        sample after its stamp, so it applies at the same sample whenever it arrives."""
        self._timed_out = False
        self.command: tuple[float, float] = (0.0, 0.0)
        """The (vx, w) the last cycle controlled towards, after stop, timeout and limits."""
        self._command_before = self.command
        """The cycle before's: the jerk limits' second previous command."""

        self._anchored = False
        """Integrated mode: q_ref and dq_ref of the last cycle are the base of the next one."""

        self._finished = False
        self._stopped = False
        self.monitor: CollisionMonitor | None = None
        """The collision monitor (services/motor/monitor.py) whose factor scales the command; None:
        not monitored (``collision_monitor.enabled = false``, or a core with no scans)."""

        self.wheel_angle_samples = 0
        self.body_pose_samples = 0
        self.target_velocity_samples = 0
        self.targets_ignored = 0
        self.command_timeouts = 0
        self.nonfinite_torques = 0
        """Cycles whose torque (or wheel speed target) came out non-finite: zero was sent instead."""

        self.cycle_state = MotorState.IDLE
        self.dq: tuple[float, float] | None = None
        self.dq_ref: tuple[float, float] | None = None
        self.q_ref: tuple[float, float] | None = None

    @property
    def state(self) -> MotorState:
        if self._stopped:
            return MotorState.STOPPED
        if self._finished:
            return MotorState.FINISHED
        if self._stamp_ns is None or not self._have_target:
            return MotorState.IDLE
        return MotorState.RUNNING

    @property
    def command_timed_out(self) -> bool:
        return self._timed_out

    def step(self, stamp_ns: int, angles: Sequence[float]) -> list[float]:
        """One control cycle for the wheel angles ``angles`` stamped ``stamp_ns`` (nanoseconds).

        Returns the torque vector: same length and order as ``angles``, zero except at the two
        wheel ids, all zero on the first sample and in states ``idle`` and ``finished``. With
        ``motor.output = "velocity"`` the vector holds wheel speed targets (rad/s) instead, zero
        in the same cycles and while stopped (:class:`~services.motor.wheel_velocity.WheelVelocityOutput`).
        """
        count = len(angles)
        if count < self._min_length:
            raise BadInput(
                f"{count} wheel angles, but wheel ids {self._left} and {self._right} need at least {self._min_length}"
            )
        q_l, q_r = angles[self._left], angles[self._right]
        previous = self._stamp_ns
        torques = [0.0] * count
        # The first sample, or the first taken back after a gap (a link down): no Δt to differentiate.
        if previous is None or self._gap.check(stamp_ns, previous):
            self.cycle_state = self.state
            self._accept(stamp_ns, q_l, q_r)
            self.dq = self.dq_ref = self.q_ref = None
            return torques
        dt = (stamp_ns - previous) / NANOSECONDS_PER_SECOND
        old_l, old_r = self.q
        dq_l, dq_r = (q_l - old_l) / dt, (q_r - old_r) / dt
        if not (abs(dq_l) <= self._max_wheel_speed and abs(dq_r) <= self._max_wheel_speed):
            raise BadInput(
                f"wheel speeds ({dq_l:g}, {dq_r:g}) rad/s (angles {q_l:g}, {q_r:g} after {old_l:g}, {old_r:g} "
                f"in {dt:g} s) beyond input.max_wheel_speed = {self._max_wheel_speed:g} rad/s"
            )
        deferred = self._deferred_target
        if deferred is not None and stamp_ns > deferred[0]:
            self._deferred_target = None
            self._apply_target(*deferred)
        state = self.state
        self.cycle_state = state
        self._accept(stamp_ns, q_l, q_r)
        self.dq = (dq_l, dq_r)
        if state is MotorState.IDLE or state is MotorState.FINISHED:
            self._release()
            self.dq_ref = self.q_ref = None
            return torques

        vx, w = self._command_velocity(stamp_ns, dt, state)
        b = self._half_axle
        dq_ref_l = (vx - b * w) / self._radius_l
        dq_ref_r = (vx + b * w) / self._radius_r
        velocity = self.velocity_output
        if velocity is not None:
            self.dq_ref, self.q_ref = (dq_ref_l, dq_ref_r), None
            targets = velocity.follow(stamp_ns, dq_ref_l, dq_ref_r, now=state is MotorState.STOPPED)
            if targets is None:
                self.nonfinite_torques += 1  # unreachable with the input bounds, as for torques
            else:
                torques[self._left], torques[self._right] = targets
            return torques
        half_dt = 0.5 * dt
        if self._integrated and self._anchored:
            old_q_ref_l, old_q_ref_r = self.q_ref  # type: ignore[misc]
            old_dq_ref_l, old_dq_ref_r = self.dq_ref  # type: ignore[misc]
            q_ref_l = old_q_ref_l + (old_dq_ref_l + dq_ref_l) * half_dt
            q_ref_r = old_q_ref_r + (old_dq_ref_r + dq_ref_r) * half_dt
        else:
            q_ref_l = q_l + (dq_ref_l + dq_l) * half_dt
            q_ref_r = q_r + (dq_ref_r + dq_r) * half_dt
            self._anchored = self._integrated
        self.dq_ref = (dq_ref_l, dq_ref_r)
        self.q_ref = (q_ref_l, q_ref_r)

        gains = self.gains
        torque_l = gains.p_gain_l * (q_ref_l - q_l) + gains.d_gain_l * (dq_ref_l - dq_l)
        torque_r = gains.p_gain_r * (q_ref_r - q_r) + gains.d_gain_r * (dq_ref_r - dq_r)
        if not (math.isfinite(torque_l) and math.isfinite(torque_r)):
            # Unreachable with the input bounds; never publish one all the same.
            self.nonfinite_torques += 1
            return torques
        torques[self._left], torques[self._right] = torque_l, torque_r
        return torques

    @property
    def time_ns(self) -> int | None:
        """The stamp of the last wheel-angle sample taken; None before the first (or a restart)."""
        return self._stamp_ns

    def restart_time_base(self) -> None:
        """A restarted simulator, whose clock started again: forget the last stamp.

        The next wheel-angle sample initialises like the very first one (zero torque, no Δt).
        The latches (``stop``, ``finish``), gains, target and counters are kept; control
        resumes from rest (limits ramp from zero, ``integrated`` re-anchors), and the target's
        age for the command timeout counts again from that next sample (a timed-out command
        stays timed out).
        """
        self._stamp_ns = None
        self._target_stamp_ns = None
        self._deferred_target = None
        if self.monitor is not None:
            self.monitor.forget()
        self._release()
        self.dq = self.dq_ref = self.q_ref = None

    def _accept(self, stamp_ns: int, q_l: float, q_r: float) -> None:
        self._stamp_ns = stamp_ns
        self.q = (q_l, q_r)
        self.wheel_angle_samples += 1
        if self._have_target and self._target_stamp_ns is None:
            self._target_stamp_ns = stamp_ns

    def _release(self) -> None:
        """Leave torque control: the next controlled cycle starts from rest and re-anchors."""
        self.command = self._command_before = (0.0, 0.0)
        self._anchored = False
        if self.velocity_output is not None:
            self.velocity_output.rest()

    def _command_velocity(self, stamp_ns: int, dt: float, state: MotorState) -> tuple[float, float]:
        monitor = self.monitor
        if state is MotorState.STOPPED:
            if monitor is not None:
                monitor.factor(stamp_ns, 0.0, 0.0)  # keeps held_by true (a scan gone stale holds)
            self.command = self._command_before = (0.0, 0.0)  # braked: the limits resume from rest
            return self.command
        vx, w = self.target
        # A timed-out command stays so until a new target, even across a restart of the time base.
        if self._timed_out or (
            self._timeout_ns and stamp_ns - self._target_stamp_ns > self._timeout_ns  # type: ignore[operator]
        ):
            vx = w = 0.0
            if not self._timed_out:
                self._timed_out = True
                self.command_timeouts += 1
        if monitor is not None:
            factor = monitor.factor(stamp_ns, vx, w)  # held: 0, slowed: slow_factor, clear: 1
            if factor != 1.0:
                vx, w = vx * factor, w * factor
        previous = self.command
        if self._limited:
            before = self._command_before
            vx = self.vx_limiter.limit(vx, previous[0], before[0], dt)
            w = self.w_limiter.limit(w, previous[1], before[1], dt)
        self._command_before, self.command = previous, (vx, w)
        return self.command

    def set_target(self, vx: float, w: float, stamp_ns: int | None = None) -> bool:
        """Accept a target body velocity; False (ignored, counted) while stopped.

        A target stamped ``stamp_ns`` applies from the first wheel sample after that stamp: one
        stamped after the last sample waits for the next (lockstep gives the same cycles whether
        the target or the sample arrives first). Its age, for the command timeout, counts from its
        stamp.

        Raises BadInput (nothing changes) for a velocity implying a wheel speed beyond
        ``input.max_wheel_speed`` (one within it but beyond the velocity limits is accepted: the
        limits clamp it), or for a ``stamp_ns`` beyond the horizon or older than the command
        timeout against the wheel-angle time, once there is one (the service always passes the
        message's stamp; None is for callers with no clock of their own).
        """
        if stamp_ns is not None and self._stamp_ns is not None:
            check_stamp_near(stamp_ns, self._stamp_ns, self._horizon_ns, self._target_history_ns, "target")
        check_target_velocity(vx, w, self.robot, self.limits)
        if self._stopped:
            self.targets_ignored += 1
            return False
        self.target_velocity_samples += 1
        if stamp_ns is not None and self._stamp_ns is not None and stamp_ns > self._stamp_ns:
            self._deferred_target = (stamp_ns, vx, w)
            return True
        self._deferred_target = None
        self._apply_target(self._stamp_ns if stamp_ns is None else stamp_ns, vx, w)
        return True

    def _apply_target(self, stamp_ns: int | None, vx: float, w: float) -> None:
        if self._stopped:
            self.targets_ignored += 1
            return
        self.target = (vx, w)
        self._have_target = True
        self._target_stamp_ns = stamp_ns
        self._timed_out = False

    def sim_pose(self, data: Sequence[float], stamp_ns: int | None = None) -> list[float]:
        """[X, Y, Z, theta] of the axle centre for a ``sim/body_pose`` vector (offsets applied).

        BadInput for a position beyond ``input.max_coordinate``, or a ``stamp_ns`` further than
        the horizon either way from the wheel-angle time, once there is one (the simulator stamps
        both with its one clock)."""
        if stamp_ns is not None and self._stamp_ns is not None:
            check_stamp_near(stamp_ns, self._stamp_ns, self._horizon_ns, self._horizon_ns, "body pose")
        pose = self._pose(data)
        check_coordinates(pose[0], pose[1], self.limits.max_coordinate)
        self.body_pose_samples += 1
        return pose

    def set_pd_gain(self, gains: PDGains) -> None:
        """All four gains, used from the next :meth:`step` on; BadInput (nothing changes) for a gain
        above ``input.max_gain``."""
        ceiling = self.limits.max_gain
        above = {name: value for name, value in msgspec.structs.asdict(gains).items() if value > ceiling}
        if above:
            raise BadInput(f"gains {above} above input.max_gain = {ceiling:g}")
        self.gains = gains

    @property
    def stopped(self) -> bool:
        """The emergency-stop latch (set by :meth:`stop`, released by :meth:`clear`)."""
        return self._stopped

    @property
    def finished(self) -> bool:
        """The finish latch (set by :meth:`finish`, released by :meth:`start`)."""
        return self._finished

    def restore(self, stopped: bool, finished: bool, gains: PDGains) -> None:
        """Take back the latches and gains a previous run of the motor left (its state file).
        BadInput (nothing changes) for gains above the ceiling."""
        self.set_pd_gain(gains)
        self._finished = finished
        if stopped:
            self.stop()

    def start(self) -> None:
        """Leave ``finished``: torque control resumes (unless stopped, or still idle)."""
        self._finished = False

    def finish(self) -> None:
        """Coast: zero torque until :meth:`start`."""
        self._finished = True

    def stop(self) -> None:
        """Emergency stop, latched: brake towards zero velocity and ignore targets until :meth:`clear`.

        The target is zeroed (clearing does not resume the old motion) and the braking bypasses
        the acceleration limits; in ``integrated`` mode the target angle re-anchors at the
        measured angle, so the wheels do not try to catch up distance lost in a collision.
        """
        self._stopped = True
        self.target = (0.0, 0.0)
        self._deferred_target = None
        self._anchored = False

    def clear(self) -> None:
        """Release the stop latch. The zero target counts as a fresh command for the timeout."""
        self._stopped = False
        self._target_stamp_ns = self._stamp_ns
        self._timed_out = False

    def status(self) -> MotorCoreStatus:
        robot, motor = self.robot, self.motor
        return MotorCoreStatus(
            state=str(self.state),
            output=motor.output,
            velocity_rate=motor.velocity_rate if self.velocity_output is not None else None,
            target_angle=str(motor.target_angle),
            gains={
                "p_gain_l": self.gains.p_gain_l,
                "p_gain_r": self.gains.p_gain_r,
                "d_gain_l": self.gains.d_gain_l,
                "d_gain_r": self.gains.d_gain_r,
            },
            geometry={
                "left_wheel_id": robot.left_wheel_id,
                "right_wheel_id": robot.right_wheel_id,
                "radius_of_left_wheel": robot.radius_of_left_wheel,
                "radius_of_right_wheel": robot.radius_of_right_wheel,
                "length_of_axle": robot.length_of_axle,
                **self.geometry._asdict(),
            },
            offsets={
                "simulated_offset_x": motor.simulated_offset_x,
                "simulated_offset_y": motor.simulated_offset_y,
                "simulated_offset_angle": motor.simulated_offset_angle,
            },
            limits=limits_status(motor),
            command_timeout=motor.command_timeout,
            target=Velocity(*self.target),
            command=Velocity(*self.command),
            command_timed_out=self._timed_out,
            counters=MotorCounters(
                nonfinite_torques=self.nonfinite_torques,
                wheel_angle_samples=self.wheel_angle_samples,
                body_pose_samples=self.body_pose_samples,
                target_velocity_samples=self.target_velocity_samples,
                targets_ignored=self.targets_ignored,
                command_timeouts=self.command_timeouts,
            ),
        )
