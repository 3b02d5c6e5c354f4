"""``invent motor``: MotorControl over zenoh (docs/protocol.md section 4), a thin shell around MotorCore.

Every ``sim/wheel_angles`` sample gets exactly one ``motor/torque`` with the sample's own
``tm`` (``motor/wheel_velocity``, wheel speed targets, with ``motor.output = "velocity"``), then
``motor/wheel_angles`` (the input, same ``tm``). A wheel-angle sample that is bad
input (undecodable, a wheel id out of range, dt <= 0) is dropped and gets no torque.
A ``sim/body_pose`` of an observed step (its mark says so, docs/protocol.md section 2.7) becomes
``motor/sim_pose/localization``, and ``motor/sim_pose/gui`` while someone subscribes to it; a
recorded run keeps both at every step it gets a body pose for.
The Motor interface answers on ``motor/gui/<method>`` and ``motor/bump/<method>``.
When the simulator's liveliness token appears and the next wheel-angle sample is not after
the last one, that sample starts a new time base (a restarted simulator's clock starts again at
0; a reconnected one's goes on, and costs nothing): services/clock/sim_watch.py.
In lockstep a wheel-angle sample is held until the drive's target its attachment says it is
owed has arrived (services/clock/lockstep.py); a target applies from the first sample after its stamp.
See docs/motor.md.
"""

from __future__ import annotations

import logging
import typing
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import msgspec

from schemas.codec import BadInput, decode
from schemas.keys import Service
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    LaserScan,
    MotorStateName,
    MotorStateReport,
    NoArguments,
    PDGains,
    StopCause,
    Time,
    TimedDoubleSeq,
    TimedVelocity,
)
from schemas.status import CollisionMonitorStatus, LockstepHolds, MotorStatus, ServiceStatus
from schemas.topics import METHOD_ARGUMENTS, Method, MethodFamily, Topic
from services.clock.lockstep import Hold, decode_mark, observed
from services.clock.sim_time import ClockRestart
from services.clock.sim_watch import HeldSample, SimulatorWatch
from services.config import Config
from services.motor.core import MotorCore
from services.motor.monitor import CollisionMonitor
from services.motor.state import SavedState, StateFile, default_state_path
from services.runtime.inputs import Delivery, NodeInput
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node, Wait
from services.service import ServiceCommand, TraceFile


class TraceRecord(msgspec.Struct, frozen=True):
    """One control cycle: one line of ``--trace FILE``.

    ``state`` is the state the cycle was computed in; ``target`` the last accepted target
    (vx, w); ``command`` the (vx, w) controlled towards after stop, timeout and limits;
    ``dq``, ``dq_ref``, ``q_ref`` are (left, right) or null when the cycle computed none
    (first sample, ``idle``, ``finished``); ``torque`` is the vector published: with
    ``motor.output = "velocity"``, the wheel speed targets (rad/s).
    """

    tm: Time
    state: str
    angles: list[float]
    q: tuple[float, float]
    dq: tuple[float, float] | None
    target: tuple[float, float]
    command: tuple[float, float]
    dq_ref: tuple[float, float] | None
    q_ref: tuple[float, float] | None
    gains: PDGains
    torque: list[float]


@dataclass(frozen=True)
class MotorOptions:
    """``invent motor``'s own options beside the robot description."""

    trace: str | None = None
    """``--trace FILE``: one JSON line per control cycle (:class:`TraceRecord`)."""
    state: Path | None = None
    """``--state FILE``: where the latches and the gains set at run time are kept across restarts
    (None: services/motor/state.py's default for the robot)."""


class MotorService:
    finished = False
    """It serves until stopped."""
    exit_code = 0

    def __init__(self, node: Node, config: Config, options: MotorOptions) -> None:
        self.node = node
        self.core = MotorCore(config.robot, config.motor, config.input, config.geometry)
        self.monitor: CollisionMonitor | None = None
        if config.collision_monitor.enabled:
            self.monitor = CollisionMonitor(
                config.robot, config.lidar, config.collision_monitor, config.input.stamp_horizon_ns
            )
            self.core.monitor = self.monitor
        self.velocity_output = config.motor.output == "velocity"
        self.outputs_published = 0
        """``motor/torque`` (or ``motor/wheel_velocity``) messages sent."""
        # Lockstep: a wheel-angle sample waits for the drive's target it is owed (the sim took it).
        self.target_hold: Hold[HeldSample] = Hold(
            Topic.DRIVE_TARGET_VELOCITY,
            self._control,
            capacity=1,
            guard=partial(node.guard, node.keys.sim_wheel_angles),
        )
        self.sim = SimulatorWatch(node, ClockRestart(config.input.stamp_horizon_ns))
        self._timeouts_logged = 0
        self._nonfinite_logged = 0
        self._warn = RateLimitedLog(node.log)
        self._trace = TraceFile.from_flag(options.trace)
        self._state_file = StateFile(options.state or default_state_path(config.robot.name))
        self.stopped_by: StopCause = ""
        """Who latched the emergency stop (``motor/state``'s ``stopped_by``)."""
        self.restored = self._restore()

        keys = node.keys
        self._state = node.latched_publisher(keys.motor_state)
        self._state_published: tuple[str, StopCause, str] = ("", "", "")
        self._publish_state()
        self._output = node.publisher(keys.motor_wheel_velocity if self.velocity_output else keys.motor_torque)
        self._wheel_angles = node.publisher(keys.motor_wheel_angles)
        self._sim_pose_gui = node.publisher(keys.motor_sim_pose_gui)
        self._sim_pose_localization = node.publisher(keys.motor_sim_pose_localization)
        # Wheel angles first: the thread waits in their channel and answers with the torque before
        # it converts the body pose, then takes the newest target (calls, posted events, come
        # before all three). A flood of targets holds one sample and delays no wheel angle.
        sim = self.sim
        node.subscribe(
            keys.sim_wheel_angles,
            TimedDoubleSeq,
            sim.held_clock(self.target_hold, self.core, "stop/finish latches, gains and target kept"),
            Delivery.EVERY,
            wakes=True,
            with_attachment=True,
        )
        node.subscribe(
            keys.sim_body_pose,
            TimedDoubleSeq,
            # Never awaited: the simulator publishes a step's body pose with its wheel angles, which decide.
            sim.stamped(keys.sim_body_pose, self._on_body_pose, awaited=lambda: False),
            Delivery.EVERY,
            with_attachment=True,
        )
        self._targets = node.subscribe(
            keys.drive_target_velocity,
            TimedVelocity,
            sim.stamped(keys.drive_target_velocity, self._on_target_velocity, awaited=lambda: self.target_hold.holding),
            Delivery.NEWEST,
        )
        self._scans: NodeInput | None = None
        if self.monitor is not None:
            # A ring channel, as the wheel angles': zenoh fills both in arrival order, and the
            # simulator publishes a step's scan after its torque, before the next step's wheel angles,
            # so when a sample is controlled every scan stamped before it is in (_control takes them
            # first; the monitor applies those stamped before the sample): a lockstep run's torques
            # are the same every run. (A callback, QUEUED, runs in a thread of its own and may come
            # after the next wheel angles.)
            self._scans = node.subscribe(
                keys.sim_scan,
                LaserScan,
                sim.stamped(keys.sim_scan, self._on_scan, awaited=lambda: False),
                Delivery.EVERY,
            )
        for family in MethodFamily:
            for method in Method:
                node.queryable(keys.method(family, method), partial(self._call, family, method), mutates=True)
        node.wait_with(self._next_wait)
        node.set_status(self.status)
        node.log.info(
            "motor control: output %s, target_angle %s, command_timeout %g s, wheel ids %d/%d",
            config.motor.output if not self.velocity_output else f"velocity at {config.motor.velocity_rate:g} Hz",
            config.motor.target_angle,
            config.motor.command_timeout,
            config.robot.left_wheel_id,
            config.robot.right_wheel_id,
        )

    def _restore(self) -> dict[str, Any] | None:
        """Take back what the state file holds; an unreadable one means starting stopped, since
        whether the robot was stopped cannot be known. Returns what was restored, for status."""
        path, log = self._state_file.path, self.node.log
        try:
            saved = self._state_file.load()
            if saved is not None:
                self.core.restore(saved.stopped, saved.finished, saved.gains)
        except (ValueError, BadInput) as error:
            self.core.stop()
            self.stopped_by = "state_file"
            log.error("state file %s unreadable (%s): starting stopped; clear to run", path, error)
            return {"from": str(path), "error": str(error), "stopped": True}
        if saved is None:
            return None
        if saved.stopped:
            self.stopped_by = "state_file"
        log.log(
            logging.WARNING if saved.stopped else logging.INFO,
            "restored from %s: %s, gains %s",
            path,
            "STOPPED (emergency stop latched: clear to run)" if saved.stopped else f"state {self.core.state}",
            msgspec.to_builtins(saved.gains),
        )
        return {"from": str(path), **msgspec.to_builtins(saved)}

    def _control(self, held: HeldSample) -> None:
        angles, attachment, mark, stamp_ns = held
        tm = angles.tm
        core = self.core
        scans = self._scans
        if scans is not None:
            while scans.take():  # every scan in, first: the monitor applies those stamped before this sample
                pass
        torques = core.step(stamp_ns, angles.data)
        # A run recorded at the observed steps keeps the control path's samples of those only.
        node = self.node
        keep = node.recording and (node.recording_every_step or observed(mark))
        self._output.put(TimedDoubleSeq(tm, torques), keep=keep)
        self._wheel_angles.put(angles, attachment, keep=keep)
        self.outputs_published += 1
        monitor = self.monitor
        if core.state != self._state_published[0] or (
            monitor is not None and monitor.held_by != self._state_published[2]
        ):
            self._publish_state()
        trace = self._trace
        if trace is not None:
            trace.write(self._trace_record(angles, torques))
        if core.nonfinite_torques != self._nonfinite_logged:
            self._nonfinite_logged = core.nonfinite_torques
            self._warn(
                "nonfinite_torque",
                logging.ERROR,
                "the %s for t = %.6f s came out non-finite (gains %s, angles %s): sent zero instead",
                "wheel speed target" if self.velocity_output else "torque",
                tm.to_seconds(),
                msgspec.to_builtins(core.gains),
                angles.data,
            )
        if core.command_timeouts != self._timeouts_logged:
            self._timeouts_logged = core.command_timeouts
            self.node.log.warning(
                "no %s for %g s of wheel-angle time: braking to zero until one arrives",
                self.node.keys.drive_target_velocity,
                core.motor.command_timeout,
            )

    def _trace_record(self, angles: TimedDoubleSeq, torques: list[float]) -> TraceRecord:
        core = self.core
        return TraceRecord(
            tm=angles.tm,
            state=core.cycle_state,
            angles=angles.data,
            q=core.q,
            dq=core.dq,
            target=core.target,
            command=core.command,
            dq_ref=core.dq_ref,
            q_ref=core.q_ref,
            gains=core.gains,
            torque=torques,
        )

    def _on_body_pose(self, pose: TimedDoubleSeq, attachment: bytes | None) -> None:
        stamp_ns = pose.tm.to_nanoseconds()
        publish = observed(decode_mark(attachment, stamp_ns))
        recording = self.node.recording_every_step
        if not (publish or recording):
            return
        sim_pose = TimedDoubleSeq(pose.tm, self.core.sim_pose(pose.data, stamp_ns))
        for publisher, put in (
            (self._sim_pose_localization, publish),
            (self._sim_pose_gui, publish and self._sim_pose_gui.matched),
        ):
            if put:
                publisher.put(sim_pose)
            elif recording:
                publisher.record(sim_pose)

    def _publish_state(self) -> None:
        """``motor/state`` (latched), when the state, who stopped the motor or why the collision
        monitor holds it has changed; one log line as a hold starts, changes cause or ends."""
        held_by = "" if self.monitor is None else self.monitor.held_by
        current = (str(self.core.state), self.stopped_by, held_by)
        if current == self._state_published:
            return
        if held_by != self._state_published[2]:
            self._log_hold(held_by, self._state_published[2])
        self._state_published = current
        stamp_ns = self.core.time_ns or 0
        state = typing.cast(MotorStateName, current[0])
        self._state.put(
            MotorStateReport(Time.from_nanoseconds(stamp_ns), state=state, stopped_by=self.stopped_by, held_by=held_by)
        )

    def _log_hold(self, held_by: str, before: str) -> None:
        t = (self.core.time_ns or 0) / NANOSECONDS_PER_SECOND
        if held_by:
            self.node.log.warning("held at t = %.3f s: %s", t, held_by)
        else:
            self.node.log.info("hold released at t = %.3f s (was: %s)", t, before)

    def _on_scan(self, scan: LaserScan) -> None:
        assert self.monitor is not None
        self.monitor.take_scan(scan, self.core.time_ns)

    def _on_target_velocity(self, velocity: TimedVelocity) -> None:
        stamp_ns = velocity.tm.to_nanoseconds()
        if not self.core.set_target(velocity.vx, velocity.w, stamp_ns):
            self.node.log.debug("stopped: target velocity ignored until clear")
        self.target_hold.took(stamp_ns)

    def _call(self, family: MethodFamily, method: Method, payload: bytes) -> ServiceStatus:
        arguments = _decode_arguments(method, payload)
        core = self.core
        if method is Method.SET_PD_GAIN:
            core.set_pd_gain(typing.cast(PDGains, arguments))
        elif method is Method.START:
            core.start()
        elif method is Method.FINISH:
            core.finish()
        elif method is Method.STOP:
            core.stop()
            self.stopped_by = family.value
        elif method is Method.CLEAR:
            core.clear()
            self.stopped_by = ""
            self.node.bad_inputs.reset()
        self._publish_state()
        try:
            self._state_file.save(SavedState(core.stopped, core.finished, core.gains))
        except OSError as error:  # the call has acted: say what will not survive a restart
            self._warn(
                "state_file",
                logging.ERROR,
                "could not write the state file %s (%s): this state will not survive a restart",
                self._state_file.path,
                error,
            )
        level = logging.WARNING if method is Method.STOP else logging.INFO
        self.node.log.log(level, "%s/%s: state %s", family, method, core.state)
        return self.node.status()

    def status(self) -> MotorStatus:
        core = self.core.status()
        core.counters.time_base_restarts = self.sim.restart.restarts
        monitor = self.monitor
        if monitor is None:
            collision = CollisionMonitorStatus(enabled=False)
        else:
            bad = self.node.bad_inputs.by_key.get(self.node.keys.sim_scan)
            collision = monitor.status(bad_scans=0 if bad is None else bad.count)
        return MotorStatus(
            **msgspec.structs.asdict(core),
            collision_monitor=collision,
            sim_alive=self.sim.alive,
            torques_published=0 if self.velocity_output else self.outputs_published,
            wheel_velocities_published=self.outputs_published if self.velocity_output else 0,
            lockstep_holds=LockstepHolds(self.target_hold.holds, self.target_hold.overflows),
            trace=None if self._trace is None else self._trace.path,
            state_file=str(self._state_file.path),
            restored=self.restored,
        )

    def _next_wait(self) -> Wait:
        """While a wheel-angle sample is held, the drive's target is what comes next, not a wheel sample."""
        return Wait(self._targets if self.target_hold.holding else None)

    def close(self) -> None:
        if self._trace is not None:
            self._trace.close()


def _decode_arguments(method: Method, payload: bytes) -> msgspec.Struct:
    """The method's arguments; an empty payload stands for ``{}`` for the argument-less methods."""
    argument_type = METHOD_ARGUMENTS[method]
    if argument_type is NoArguments and not payload.strip():
        return NoArguments()
    try:
        return decode(argument_type, payload)
    except BadInput as error:
        raise BadInput(f"{method}: {error}") from None


COMMAND = ServiceCommand(service=Service.MOTOR, factory=MotorService)
