"""One robot of the sim bridge's world as the bridge serves it (:class:`RobotLink`): its node's
publishers, inputs, liveliness watches and ``motor/bump/stop`` querier, what each step publishes
(its wheel angles, marked; its body pose and clock at the observed steps), its bumps and its status.
Who is there is :mod:`sim_bridge.liveness`'s; which torque a step applies, :mod:`sim_bridge.torque_policy`'s."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import msgspec
import zenoh

from schemas.codec import encode
from schemas.keys import Service, ServiceName
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    BumpEvent,
    NoArguments,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.status import ImuStatus, LidarStatus, NearestHit, SensorsStatus, SimCounters, SimStatus, SimWorldStatus
from schemas.topics import Method, MethodFamily
from services.clock.lockstep import OUTPUTS, StampedOutput, TickBarrier, encode_mark
from services.clock.observation import ObservedSteps
from services.config import SimConfig, SimMode
from services.config.sections import MotorOutput
from services.runtime.inputs import Delivery, NodeInput
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node
from sim_bridge.latency import TorqueLatency
from sim_bridge.liveness import Liveness
from sim_bridge.progress import RunProgress
from sim_bridge.status import late_fraction, nearest_hit, planar_pose, robot_summary
from sim_bridge.torque_policy import TorquePolicy

if TYPE_CHECKING:
    from sim_bridge.engine import Contact, RobotPlant

BUMP_STOP_TIMEOUT_S = 1.0
"""How long a ``motor/bump/stop`` call stays open for its reply."""
_BUMP_STOP_PAYLOAD = encode(NoArguments())

COUNTERS = (
    "torques_applied",
    "long_waits",
    "missing_torques",
    "stale_torques",
    "bumps",
    "bump_stop_calls",
    "bump_stop_acks",
    "bump_stop_errors",
    "realtime_resyncs",
    "realtime_late_steps",
    "refused_participants",
    "braked_steps",
    "scans",
    "scan_rays",
    "imu_samples",
)
"""The counters of ``sim/status`` (docs/sim.md explains each)."""


class TorqueLog:
    """The log lines of one robot's torque policy (:class:`~sim_bridge.torque_policy.TorqueEvents`)."""

    def __init__(self, log: logging.Logger, warn: RateLimitedLog, parameters: SimConfig, prefix: str) -> None:
        self._log, self._warn, self._parameters, self._prefix = log, warn, parameters, prefix

    def waiting(self, tm_ns: int, waited_s: float) -> None:
        self._warn(
            "long_torque_wait",
            logging.WARNING,
            "%sstill waiting for motor/torque for t = %.3f s after %.1f s: its motor control is alive",
            self._prefix,
            tm_ns / NANOSECONDS_PER_SECOND,
            waited_s,
        )

    def silent(self) -> None:
        self._log.info(
            "%smotor control alive after the first step: stepping at real-time pace until it answers", self._prefix
        )

    def answering(self) -> None:
        self._log.info("%smotor control answers: steps wait for its torques", self._prefix)

    def braking(self) -> None:
        self._log.warning(
            "%sno torque for %g s: braking the wheels until one comes", self._prefix, self._parameters.brake_after
        )


@dataclass(frozen=True)
class MotorSeam:
    """What a robot's motor sends (its ``motor.output``) and the bound on wheel speed targets
    (its ``input.max_wheel_speed``): the link takes that key and nothing else."""

    output: MotorOutput = "torque"
    max_wheel_speed: float = math.inf


class RobotLink:
    """One robot of the world as the bridge serves it: its node (keys, liveliness token, status),
    publishers and inputs, its lockstep barrier and observed steps, its counters and torque
    latency, its torque policy and who is there for it. A one-robot sim has one link, on the
    service's own node; a fleet sim one per robot, their nodes on the same executor, so the loop's
    one thread serves them all."""

    def __init__(
        self,
        node: Node,
        body: RobotPlant,
        parameters: SimConfig,
        *,
        step_ns: int,
        progress: RunProgress,
        prefix: str,
        world_status: Callable[[], SimWorldStatus],
        seam: MotorSeam = MotorSeam(),
    ) -> None:
        self.node = node
        self.seam = seam
        self.body = body
        self.name = body.name
        self.prefix = prefix
        """What a log line about this robot starts with: its name, in a fleet."""
        self._world_status = world_status
        """The part of the status that is the world's (:meth:`~sim_bridge.status.RunStatus.world_status`)."""
        self._lockstep = parameters.mode == SimMode.LOCKSTEP
        self.barrier = TickBarrier()
        self.outputs: dict[ServiceName, NodeInput | None] = {}
        """Lockstep: the participants' output channels, to wait in at their ticks."""
        self.observation = ObservedSteps(parameters.observe_every)
        self.marks = (b"", b"")
        """The attachment of a step's wheel angles, (not observed, observed): what the barrier owes
        (in lockstep) and whether the step is observed. Encoded when they change, not at every step."""
        self.owed_changed()
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.bump_stops_open = 0
        """``motor/bump/stop`` calls not yet finished (answered, refused or timed out): in lockstep
        the next step waits for them (:meth:`sim_bridge.loops.Loop.run_lockstep`)."""
        self.clock: tuple[TimedDoubleSeq, bytes] | None = None
        """(wheel angles, mark) of an observed step published, while its ``sim/clock`` waits."""
        self.latency = TorqueLatency(step_ns)
        self._lidar, self._imu = body.lidar, body.imu
        self.next_sensor_ns: float = 0 if self._lidar or self._imu else math.inf
        """The stamp of the next step at which a sensor of the robot is due (inf: it has none)."""
        self.nearest: NearestHit | None = None
        """What the latest scan's nearest ray hit (``body``, ``range``); None when it hit nothing."""
        warn = RateLimitedLog(node.log)
        self.torque = TorquePolicy(
            body,
            parameters,
            step_ns,
            progress=progress,
            counters=self.counters,
            latency=self.latency,
            events=TorqueLog(node.log, warn, parameters, prefix),
            now_ns=time.perf_counter_ns,
            max_wheel_speed=seam.max_wheel_speed,
        )
        self.liveness = Liveness(
            barrier=self.barrier,
            observation=self.observation,
            torque=self.torque,
            owed_changed=self.owed_changed,
            take_output=self._take_output,
            progress=progress,
            counters=self.counters,
            parameters=parameters,
            log=node.log,
            warn=warn,
            prefix=prefix,
        )
        self._declare()

    def _declare(self) -> None:
        node, keys, liveness = self.node, self.node.keys, self.liveness
        self.pose_publisher = node.publisher(keys.sim_body_pose)
        self.angles_publisher = node.publisher(keys.sim_wheel_angles)
        self.clock_publisher = node.publisher(keys.sim_clock)
        self.bump_publisher = node.publisher(keys.sim_bump)
        self.scan_publisher = node.publisher(keys.sim_scan)
        self.imu_publisher = node.publisher(keys.sim_imu)
        self.world_publisher = node.latched_publisher(keys.sim_world)
        # Lockstep waits in the torque channel's receive itself, and in a participant's output
        # channel at its ticks; realtime waits for its step's deadline, which a posted torque must
        # interrupt.
        lockstep = self._lockstep
        delivery = Delivery.EVERY if lockstep else Delivery.QUEUED
        velocity = self.seam.output == "velocity"
        self.torque_input = node.subscribe(
            keys.motor_wheel_velocity if velocity else keys.motor_torque,
            TimedDoubleSeq,
            self.torque.on_wheel_velocity if velocity else self.torque.on_torque,
            delivery,
            wakes=lockstep,
            with_attachment=True,
        )
        for service, message_type in ((Service.DRIVE, TimedVelocity), (Service.LOCALIZATION, TimedPosition)):
            self.outputs[service] = node.subscribe(
                keys.topic(OUTPUTS[service]),
                message_type,
                partial(liveness.on_output, service),
                delivery,
                with_attachment=True,
            )
        self._ticks_watch = node.session.liveliness().declare_subscriber(
            keys.every_ticks, self._on_ticks_token, history=True
        )
        self._observers_watch = node.session.liveliness().declare_subscriber(
            keys.every_observes, self._on_observes_token, history=True
        )
        self._bump_stop = node.querier(keys.method(MethodFamily.BUMP, Method.STOP), timeout=BUMP_STOP_TIMEOUT_S)
        node.watch(Service.MOTOR, liveness.set_motor_alive)
        node.set_status(self.status)

    def _take_output(self, service: ServiceName, output: str) -> None:
        """Subscribe a user participant's output (on the service thread, when its token appears):
        only its stamp is read. Kept for the run: a participant that comes back outputs there again."""
        if service in self.outputs:
            return
        self.outputs[service] = self.node.subscribe(
            f"{self.node.keys.prefix}/{output}",
            StampedOutput,
            partial(self.liveness.on_output, service),
            Delivery.EVERY if self._lockstep else Delivery.QUEUED,
            with_attachment=True,
        )

    # --- zenoh callbacks: they only hand over to the service thread ---

    def _on_ticks_token(self, sample: zenoh.Sample) -> None:
        self.node.post(
            partial(self.liveness.participant_changed, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
        )

    def _on_observes_token(self, sample: zenoh.Sample) -> None:
        self.node.post(
            partial(self.liveness.observer_changed, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
        )

    def _on_bump_stop_reply(self, reply: zenoh.Reply) -> None:
        result = reply.result
        ok = isinstance(result, zenoh.Sample)
        reason = "" if ok else result.payload.to_string()
        self.node.post(partial(self._record_bump_stop_reply, ok, reason))

    def _on_bump_stop_done(self) -> None:
        self.node.post(self._bump_stop_finished)

    # --- service thread ---

    def _bump_stop_finished(self) -> None:
        self.bump_stops_open -= 1

    def _record_bump_stop_reply(self, ok: bool, reason: str) -> None:
        if ok:
            self.counters["bump_stop_acks"] += 1
        else:
            self.counters["bump_stop_errors"] += 1
            self.node.log.warning("%smotor/bump/stop answered with an error: %s", self.prefix, reason)

    def publish_sensors(self, tm_ns: int, tm: Time) -> None:
        """Publish the scan and the IMU sample due at ``tm_ns`` (the loop calls this only once
        ``next_sensor_ns`` has come), once the step's torque is in and before the next step's wheel
        angles: the motor applies a scan from the first cycle after it (docs/protocol.md 4.10)."""
        body, lidar, imu = self.body, self._lidar, self._imu
        upcoming = math.inf
        if lidar is not None:
            if lidar.schedule.due(tm_ns):
                scan = body.scan(tm)
                self.scan_publisher.put(scan)
                self.counters["scans"] += 1
                self.counters["scan_rays"] += len(scan.ranges)
                self.nearest = nearest_hit(scan)
            upcoming = lidar.schedule.next_ns
        if imu is not None:
            if imu.schedule.due(tm_ns):
                self.imu_publisher.put(body.imu_sample(tm))
                self.counters["imu_samples"] += 1
            upcoming = min(upcoming, imu.schedule.next_ns)
        self.next_sensor_ns = upcoming

    def publish_state(self, step_index: int, tm_ns: int, tm: Time, every_step: bool, final: bool) -> None:
        """Publish this step's wheel angles, then its body pose if it is observed (or the run is
        recorded at ``every_step``): the motor converts the pose once it has answered the wheel
        angles, in the same wake. The step's clock waits for :meth:`after_torque`. The ``final``
        state of a finite run is observed, whatever the step."""
        body = self.body
        observed = self.observation.observed(step_index, tm_ns) or final
        mark = self.marks[observed]
        angles = TimedDoubleSeq(tm, body.wheel_angles())
        self.latency.published(tm_ns, time.perf_counter_ns())
        self.angles_publisher.put(angles, mark, keep=observed or every_step)
        if observed or every_step:
            self.pose_publisher.put(TimedDoubleSeq(tm=tm, data=body.body_pose()), mark)
        if observed:
            self.clock = (angles, mark)

    def after_torque(self, tm_ns: int) -> None:
        """Once the step's torque is in, or its wait is over: the sensors due at ``tm_ns``
        (:meth:`publish_sensors`), then the step's ``sim/clock`` if it is observed. The rays are cast
        while nothing waits for the sim (with ``--rt`` the control path shares one CPU: cast before
        the torque, a scan delayed it past the step) and before the next step's wheel angles, from
        whose cycle the motor applies the scan. The drive's command (and the ROS 2 bridge's
        messages) are computed while the simulator steps, not while the motor computes the torque.
        Called again in a step, it does nothing more."""
        if tm_ns >= self.next_sensor_ns:
            self.publish_sensors(tm_ns, Time.from_nanoseconds(tm_ns))
        pending, self.clock = self.clock, None
        if pending is not None:
            self.clock_publisher.put(*pending)

    def bump(self, contact: Contact, tm: Time) -> None:
        self.counters["bumps"] += 1
        self.node.log.info(
            "%sbump: began touching %r at (%.3f, %.3f, %.3f), t = %.3f s; calling motor/bump/stop",
            self.prefix,
            contact.obstacle,
            contact.x,
            contact.y,
            contact.z,
            tm.to_seconds(),
        )
        self.bump_publisher.put(BumpEvent(tm=tm, obstacle=contact.obstacle, x=contact.x, y=contact.y, z=contact.z))
        self.counters["bump_stop_calls"] += 1
        self.bump_stops_open += 1
        self._bump_stop.get(
            zenoh.handlers.Callback(self._on_bump_stop_reply, self._on_bump_stop_done), payload=_BUMP_STOP_PAYLOAD
        )

    def owed_changed(self) -> None:
        owed = self.barrier.owed() if self._lockstep else None
        self.marks = (encode_mark(owed, observed=False), encode_mark(owed, observed=True))

    def summary(self) -> str:
        return robot_summary(self.counters, planar_pose(self.body.body_pose()))

    def status(self) -> SimStatus:
        world = self._world_status()
        torque = self.torque
        return SimStatus(
            **msgspec.structs.asdict(world),
            motor_alive=torque.motor_alive,
            motor_silent=torque.silent,
            torques=list(self.body.applied_torques),
            pose=planar_pose(self.body.body_pose()),
            counters=SimCounters(**self.counters),
            torque_latency=self.latency.summary(),
            late_fraction=late_fraction(self.counters, world.steps, self._lockstep),
            lockstep_participants=self.barrier.status(),
            dropped_participants=list(self.liveness.dropped),
            observed_steps=self.observation.count,
            observed_rates=self.observation.rates(),
            drive_ended=self.liveness.drive_ended,
            braking=self.body.braking,
            sensors=SensorsStatus(
                lidar=None if self._lidar is None else LidarStatus(self._lidar.config.rate, self.nearest),
                imu=None if self._imu is None else ImuStatus(self._imu.config.rate),
            ),
        )

    def close(self) -> None:
        self._ticks_watch.undeclare()
        self._observers_watch.undeclare()
        self._bump_stop.undeclare()
