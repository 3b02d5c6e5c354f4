"""``invent sim``: the PyBullet simulator bridge (docs/protocol.md section 6), a thin shell around the simulator core.

Every step publishes ``sim/wheel_angles`` stamped with simulation time, applies the wheel
torques and steps. The observed steps (services/clock/observation.py: every ``sim.observe_every``-th
step and each tick of a rate someone holds a token for) also publish ``sim/clock`` and
``sim/body_pose``; a recorded run publishes the body pose at every step. Each step's wheel angles
carry its :class:`~services.clock.lockstep.StepMark`: whether it is observed, and in lockstep
what it owes. A finite run (``--duration S``) ends by publishing the state at S, observed, and
(in lockstep) taking the torque that answers it without applying it.

- **lockstep** (default): before stepping, wait for the ``motor/torque`` whose ``tm`` is this
  step's; a torque with any other ``tm`` is stale (counted, ignored). The wait happens only
  while a motor control is alive (its liveliness token ``motor/alive``): with none, steps run
  without waiting, zero torque. An answer later than ``sim.lockstep_timeout`` means zero
  torque, a (rate-limited) warning and the next step. After ``sim.lockstep_max_late`` late
  answers in a row the motor control counts as silent: each step then waits only one
  real-time period for its torque (the sim runs at real-time pace, zero torque, slow enough
  for a motor control to work off its backlog) until a torque from it arrives again.
  The whole loop is in lockstep too (services/clock/lockstep.py): at each tick of a participant (the
  drive, the localization: liveliness tokens ``<service>/ticks/<rate>``) the step also waits for
  its output, and the marks of the steps' wheel angles say what the motor and odometry hold
  their samples for. ``--wait-for`` and ``--until-drive-ends`` make a run start and end at
  the same step every time.
- **realtime**: steps paced to the wall clock times ``sim.realtime_factor``; each applies the
  newest torque, or zero when the newest is older than ``sim.torque_max_age``. A step whose own
  torque (the answer to its wheel angles) has not arrived when it is stepped counts as late.

In both modes the status reports the torque latency (wheel angles published -> the torque with
their ``tm`` received) as percentiles over the most recent steps (:mod:`sim_bridge.latency`).

When the robot begins touching an obstacle it publishes ``sim/bump`` and calls
``motor/bump/stop`` without waiting for the answer (the reply is only counted).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import msgspec
import zenoh

from schemas.codec import BadInput, encode
from schemas.keys import Keys, Method, MethodFamily, Service, parse_observes_key, parse_ticks_key
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    BumpEvent,
    NoArguments,
    SimWorld,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from services.clock.lockstep import FINAL, OUTPUTS, TickBarrier, encode_mark
from services.clock.observation import ObservedSteps
from services.config import Config, RobotConfig, SimMode
from services.fleet.description import Fleet
from services.runtime.executor import STOP_POLL_S
from services.runtime.inputs import Delivery, NodeInput
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node
from services.service import ServiceCommand
from sim_bridge.latency import TorqueLatency
from sim_bridge.world import InitialPose, obstacles, read_world, resolve_world

if TYPE_CHECKING:
    from sim_bridge.simulator import Contact, SimulatedRobot

BUMP_STOP_TIMEOUT_S = 1.0
"""How long a ``motor/bump/stop`` call stays open for its reply."""
MAX_REALTIME_LAG_S = 0.1
"""Realtime mode: a loop this far behind the wall clock restarts its schedule instead of bursting."""
START_HANDSHAKE_TIMEOUT_S = 5.0
"""Lockstep: how long the first step waits for the participants to see this simulator."""
_BUMP_STOP_PAYLOAD = encode(NoArguments())


COUNTERS = (
    "torques_applied",
    "late_torques",
    "missing_torques",
    "stale_torques",
    "bumps",
    "bump_stop_calls",
    "bump_stop_acks",
    "bump_stop_errors",
    "realtime_resyncs",
    "realtime_late_steps",
    "tick_timeouts",
    "braked_steps",
)
"""The counters of ``sim/status`` (docs/sim.md explains each)."""


class RobotLink:
    """One robot of the world as the bridge serves it: its node (keys, liveliness token, status),
    publishers and inputs, its motor's state, its lockstep barrier and observed steps, its counters
    and torque latency. A one-robot sim has one link, on the service's own node; a fleet sim one
    per robot, their nodes on the same executor, so the loop's one thread serves them all."""

    def __init__(self, service: SimService, node: Node, body: SimulatedRobot) -> None:
        self.service = service
        self.node = node
        self.body = body
        self.name = body.name
        self.barrier = TickBarrier()
        self.outputs: dict[Service, NodeInput | None] = {}
        """Lockstep: the participants' output channels, to wait in at their ticks."""
        self.observation = ObservedSteps(service.parameters.observe_every)
        self.marks = (b"", b"")
        """The attachment of a step's wheel angles, (not observed, observed): what the barrier owes
        (in lockstep) and whether the step is observed. Encoded when they change, not at every step."""
        self.owed_changed()
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.motor_alive = False
        self.motor_silent = False
        """Alive but not answering: lockstep steps at real-time pace until its next torque."""
        self.motor_lost = False
        """Its motor control was alive and has gone: until one is back, nothing its participants
        command can move the robot, so the world does not wait at their ticks (in a fleet, the
        other robots go on at their pace)."""
        self.late_in_a_row = 0
        self.drive_ended = False
        """The drive's last target (its scenario ended) has arrived, or the drive has gone: its token
        and its last target travel separately, and the token may come first."""
        self.awaited_ns = -1
        self.answered = False
        self.newest_torque: list[float] | None = None
        self.newest_ns = -1
        self.clock: tuple[TimedDoubleSeq, bytes] | None = None
        """(wheel angles, mark) of an observed step published, while its ``sim/clock`` waits."""
        self.latency = TorqueLatency(service.sim.step_ns)
        brake_after = service.parameters.brake_after
        self.brake_steps = (
            None if brake_after is None else max(1, round(brake_after * NANOSECONDS_PER_SECOND / service.sim.step_ns))
        )
        """Steps without a torque after which the wheels are braked (``sim.brake_after``)."""
        self.torque_step = 0
        """The step at which a torque of the motor control was last applied (or the run began)."""
        self.warn = RateLimitedLog(node.log)
        self._declare()

    def _declare(self) -> None:
        node, keys = self.node, self.node.keys
        self.pose_publisher = node.publisher(keys.sim_body_pose)
        self.angles_publisher = node.publisher(keys.sim_wheel_angles)
        self.clock_publisher = node.publisher(keys.sim_clock)
        self.bump_publisher = node.publisher(keys.sim_bump)
        self.world_publisher = node.latched_publisher(keys.sim_world)
        # Lockstep waits in the torque channel's receive itself, and in a participant's output
        # channel at its ticks; realtime waits for its step's deadline, which a posted torque must
        # interrupt.
        lockstep = self.service.mode == SimMode.LOCKSTEP
        delivery = Delivery.EVERY if lockstep else Delivery.QUEUED
        self.torque_input = node.subscribe(
            keys.motor_torque, TimedDoubleSeq, self._on_torque, delivery, wakes=lockstep, with_attachment=True
        )
        for service, message_type in ((Service.DRIVE, TimedVelocity), (Service.LOCALIZATION, TimedPosition)):
            self.outputs[service] = node.subscribe(
                keys.topic(OUTPUTS[service]),
                message_type,
                partial(self._on_output, service),
                delivery,
                with_attachment=True,
            )
        self._ticks_watch = node.session.liveliness().declare_subscriber(
            keys.every_ticks, self._on_ticks_token, history=True
        )
        self._observers_watch = node.session.liveliness().declare_subscriber(
            keys.every_observes, self._on_observes_token, history=True
        )
        self._bump_stop = node.session.declare_querier(
            keys.method(MethodFamily.BUMP, Method.STOP), timeout=BUMP_STOP_TIMEOUT_S
        )
        node.watch(Service.MOTOR, self.set_motor_alive)
        node.set_status(self.status)

    # --- zenoh callbacks: they only hand over to the service thread ---

    def _on_ticks_token(self, sample: zenoh.Sample) -> None:
        self.node.post(partial(self._participant_changed, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

    def _on_observes_token(self, sample: zenoh.Sample) -> None:
        self.node.post(partial(self._observer_changed, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

    def _on_bump_stop_reply(self, reply: zenoh.Reply) -> None:
        result = reply.result
        ok = isinstance(result, zenoh.Sample)
        reason = "" if ok else result.payload.to_string()
        self.node.post(partial(self._record_bump_stop_reply, ok, reason))

    # --- service thread ---

    def set_motor_alive(self, alive: bool) -> None:
        if alive == self.motor_alive:
            return
        self.motor_lost = self.motor_alive and not alive
        self.motor_alive = alive
        self.set_motor_silent(False)
        lockstep = self.service.mode == SimMode.LOCKSTEP
        if alive:
            effect = "steps wait for its torques" if lockstep else "applying its torques"
        else:
            effect = "stepping on with zero torque" if lockstep else "zero torque"
        self.node.log.info("%smotor control %s: %s", self.service.prefix(self), "alive" if alive else "gone", effect)

    def set_motor_silent(self, silent: bool) -> None:
        self.late_in_a_row = 0
        if silent == self.motor_silent:
            return
        self.motor_silent = silent
        prefix = self.service.prefix(self)
        if silent:
            self.node.log.warning(
                "%smotor control alive but silent for %d steps: stepping at real-time pace until it answers",
                prefix,
                self.service.parameters.lockstep_max_late,
            )
        elif self.motor_alive:
            self.node.log.info("%smotor control answers again: steps wait for its torques", prefix)

    def _participant_changed(self, key: str, alive: bool) -> None:
        parsed = parse_ticks_key(key)
        if parsed is None or parsed[0] not in OUTPUTS:
            return
        service, rate_hz = parsed
        lockstep, prefix = self.service.mode == SimMode.LOCKSTEP, self.service.prefix(self)
        if alive:
            self.observation.add(key, rate_hz, self.service.present())
            self.barrier.announce(service, rate_hz, from_start=not self.service.started)
            if lockstep:
                self.node.log.info(
                    "%s%s ticks at %g Hz: steps at its ticks wait for its output", prefix, service, rate_hz
                )
            return
        self.observation.remove(key)
        if self.barrier.withdraw(service):
            self.owed_changed()
            if lockstep:
                self.node.log.info("%s%s gone: its ticks are not waited for", prefix, service)
            if service is Service.DRIVE:
                self.drive_ended = True

    def _observer_changed(self, key: str, alive: bool) -> None:
        parsed = parse_observes_key(key)
        if parsed is None:
            return
        service, rate_hz = parsed
        if alive:
            self.observation.add(key, rate_hz, self.service.present())
            self.node.log.info(
                "%s%s observes at %g Hz: those steps are observed too", self.service.prefix(self), service, rate_hz
            )
        else:
            self.observation.remove(key)

    def _on_output(self, service: Service, message: TimedVelocity | TimedPosition, attachment: bytes | None) -> None:
        final = attachment == FINAL
        self.barrier.took(service, message.tm.to_nanoseconds(), self.service.published_ns, final=final)
        self.owed_changed()
        if final and service is Service.DRIVE and not self.drive_ended:
            self.drive_ended = True
            self.node.log.info(
                "%sthe drive's scenario ended at t = %.3f s", self.service.prefix(self), message.tm.to_seconds()
            )

    def _record_bump_stop_reply(self, ok: bool, reason: str) -> None:
        if ok:
            self.counters["bump_stop_acks"] += 1
        else:
            self.counters["bump_stop_errors"] += 1
            self.node.log.warning("%smotor/bump/stop answered with an error: %s", self.service.prefix(self), reason)

    def _on_torque(self, torque: TimedDoubleSeq, _attachment: bytes | None) -> None:
        # Taken with its (unused) attachment: the input then calls this directly, at every step.
        body = self.body
        if len(torque.data) != body.wheel_count:
            raise BadInput(f"{len(torque.data)} torques, expected {body.wheel_count} (one per wheel id)")
        tm_ns = torque.tm.to_nanoseconds()
        self.latency.answered(tm_ns, time.perf_counter_ns())
        if self.service.lockstep:
            if self.motor_silent:
                self.set_motor_silent(False)
            if tm_ns != self.awaited_ns or self.answered:
                self.counters["stale_torques"] += 1
                return
            body.set_torques(torque.data)
            self.answered = True
        elif tm_ns > self.service.published_ns:
            published_ns = self.service.published_ns
            raise BadInput(
                f"torque stamped t = {tm_ns / NANOSECONDS_PER_SECOND:.6f} s, after the latest step "
                f"(t = {published_ns / NANOSECONDS_PER_SECOND:.6f} s): from the future"
            )
        elif tm_ns > self.newest_ns:
            self.newest_torque, self.newest_ns = torque.data, tm_ns

    def publish_state(self, step_index: int, tm_ns: int, tm: Time, every_step: bool, final: bool) -> None:
        """Publish this step's wheel angles, then its body pose if it is observed (or the run is
        recorded at ``every_step``): the motor converts the pose once it has answered the wheel
        angles, in the same wake. The step's clock waits for :meth:`publish_clock`. The ``final``
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

    def publish_clock(self) -> None:
        """Publish this step's ``sim/clock`` if it is observed, once the step's torque is in or its
        wait is over: the drive's command (and the ROS 2 bridge's messages) are then computed while
        the simulator steps, not while the motor computes the torque."""
        pending, self.clock = self.clock, None
        if pending is not None:
            self.clock_publisher.put(*pending)

    def bump(self, contact: Contact, tm: Time) -> None:
        self.counters["bumps"] += 1
        self.node.log.info(
            "%sbump: began touching %r at (%.3f, %.3f, %.3f), t = %.3f s; calling motor/bump/stop",
            self.service.prefix(self),
            contact.obstacle,
            contact.x,
            contact.y,
            contact.z,
            tm.to_seconds(),
        )
        self.bump_publisher.put(BumpEvent(tm=tm, obstacle=contact.obstacle, x=contact.x, y=contact.y, z=contact.z))
        self.counters["bump_stop_calls"] += 1
        self._bump_stop.get(self._on_bump_stop_reply, payload=_BUMP_STOP_PAYLOAD)

    def torque_settled(self) -> bool:
        """The wait for this step's torque is over: it came, or the motor has gone."""
        return self.answered or not self.motor_alive

    def begin_torque_wait(self, tm_ns: int) -> None:
        self.awaited_ns, self.answered = tm_ns, False

    def end_torque_wait(self, final: bool = False) -> None:
        """After the wait for this step's torque: count it, or apply zero torque (or brake). The
        ``final`` state's torque is taken, never applied: the run ends there."""
        self.awaited_ns = -1
        if final:
            return
        if self.answered:
            self.late_in_a_row = 0
            self.counters["torques_applied"] += 1
            self.torque_step = self.service.sim.step_index
        else:
            self.no_torque()

    def no_torque(self) -> None:
        """No torque for this step: zero torque, or the brakes once there has been none for
        ``sim.brake_after`` (the motor control gone, silent, or cut off by a link down)."""
        if self.brake_steps is not None and self.service.sim.step_index - self.torque_step >= self.brake_steps:
            if not self.body.braking:
                self.node.log.warning(
                    "%sno torque for %g s: braking the wheels until one comes",
                    self.service.prefix(self),
                    self.service.parameters.brake_after,
                )
            self.body.brake()
            self.counters["braked_steps"] += 1
        else:
            self.body.set_zero_torques()

    def late(self, tm_ns: int) -> None:
        parameters = self.service.parameters
        self.counters["late_torques"] += 1
        self.warn(
            "late_torque",
            logging.WARNING,
            "%sno motor/torque for t = %.3f s within %.3f s: zero torque",
            self.service.prefix(self),
            tm_ns / NANOSECONDS_PER_SECOND,
            parameters.lockstep_timeout,
        )
        self.late_in_a_row += 1
        if self.late_in_a_row >= parameters.lockstep_max_late:
            self.set_motor_silent(True)

    def tick_timed_out(self, service: Service, tm_ns: int) -> None:
        self.barrier.gave_up(service)
        self.counters["tick_timeouts"] += 1
        self.warn(
            f"tick_timeout_{service}",
            logging.WARNING,
            "%sno %s for t = %.3f s within %.3f s: stepping on; waiting for it again once it outputs",
            self.service.prefix(self),
            OUTPUTS[service],
            tm_ns / NANOSECONDS_PER_SECOND,
            self.service.parameters.lockstep_timeout,
        )

    def realtime_torque(self, tm_ns: int, max_age_ns: int) -> None:
        if self.newest_ns != tm_ns:
            self.counters["realtime_late_steps"] += 1
        newest = self.newest_torque
        if newest is not None and 0 <= tm_ns - self.newest_ns <= max_age_ns:
            self.body.set_torques(newest)
            self.counters["torques_applied"] += 1
            self.torque_step = self.service.sim.step_index
        else:
            self.no_torque()
            self.counters["missing_torques"] += 1

    def owed_changed(self) -> None:
        owed = self.barrier.owed() if self.service.mode == SimMode.LOCKSTEP else None
        self.marks = (encode_mark(owed, observed=False), encode_mark(owed, observed=True))

    def planar_pose(self) -> dict[str, float]:
        x, y, _z, r00, _r01, _r02, r10 = self.body.body_pose()[:7]
        return {"x": x, "y": y, "theta": math.atan2(r10, r00)}

    def summary(self) -> str:
        pose = self.planar_pose()
        counters = ", ".join(f"{name} {count}" for name, count in self.counters.items())
        return f"{counters}; pose x {pose['x']:.4f} m, y {pose['y']:.4f} m, theta {pose['theta']:.4f} rad"

    def late_fraction(self) -> float:
        """Steps whose torque came late: past the timeout (lockstep), after the step (realtime)."""
        steps = self.service.sim.step_index
        late = self.counters["late_torques" if self.service.mode == SimMode.LOCKSTEP else "realtime_late_steps"]
        return late / steps if steps else 0.0

    def status(self) -> dict[str, Any]:
        status = self.service.world_status()
        status.update(
            motor_alive=self.motor_alive,
            motor_silent=self.motor_silent,
            torques=list(self.body.applied_torques),
            pose=self.planar_pose(),
            counters=dict(self.counters),
            torque_latency=self.latency.summary(),
            late_fraction=self.late_fraction(),
            lockstep_participants=self.barrier.status(),
            observed_steps=self.observation.count,
            observed_rates=self.observation.rates(),
            drive_ended=self.drive_ended,
            braking=self.body.braking,
        )
        return status

    def close(self) -> None:
        self._ticks_watch.undeclare()
        self._observers_watch.undeclare()
        self._bump_stop.undeclare()


@dataclass(frozen=True)
class SimOptions:
    """``invent sim``'s own options beside the robot description."""

    duration: float | None = None
    """Simulate this many seconds, then exit 0 (None: until stopped)."""
    until_drive_ends: bool = False
    """Hold at the drive's last target, answering status, until stopped (``invent up``'s)."""
    wait_for: tuple[Service, ...] = ()
    """The services to wait for before the first step."""
    gui: bool = False
    fleet: Fleet | None = None
    """Every robot of this fleet in one world, each robot's keys under its name."""
    fleet_robots: tuple[RobotConfig, ...] = ()
    """With ``fleet``: each robot's description, in the fleet's order."""


class SimService:
    def __init__(self, node: Node, config: Config, options: SimOptions) -> None:
        self.node = node
        self.parameters = config.sim
        self.mode = config.sim.mode
        self.lockstep = self.mode == SimMode.LOCKSTEP
        """The mode, as the per-step code asks it (an enum comparison costs more than the attribute)."""
        self.duration: float | None = options.duration
        self.until_drive_ends: bool = options.until_drive_ends
        self.wait_for: list[Service] = list(options.wait_for)
        self.started = False
        self._started_at: float | None = None
        self._stopped_at: float | None = None
        self.finished = False
        self.exit_code = 0
        self.published_ns = -1
        """The stamp of the latest step published: no torque can answer a later one."""
        self._silent_wait_s = config.sim.step / config.sim.realtime_factor
        self._max_age_ns = round(config.sim.torque_max_age * NANOSECONDS_PER_SECOND)
        # Imported here, not at the top: every `invent` command imports this module for its flags,
        # and importing PyBullet prints its build banner.
        from sim_bridge.simulator import Placement, Simulator

        self.fleet = options.fleet
        self.world_file = resolve_world(config.sim.world)
        self.world = read_world(self.world_file)
        placements: list[Placement] = []
        if self.fleet is not None:
            for robot, description in zip(self.fleet.robots, options.fleet_robots, strict=True):
                start = robot.start
                placements.append(
                    Placement(robot.name, description, InitialPose(x=start.x, y=start.y, theta=start.theta))
                )
        self.sim = Simulator(config.robot, config.sim, self.world, gui=options.gui, fleet=placements)
        self._end_step = (
            math.inf
            if options.duration is None
            else round(options.duration * NANOSECONDS_PER_SECOND / self.sim.step_ns)
        )
        self.links: list[RobotLink] = []
        try:
            for index, body in enumerate(self.sim.robots):
                robot_node = (
                    node
                    if index == 0
                    else Node(
                        node.session,
                        Keys(body.name),
                        Service.SIM,
                        executor=node.executor,
                        journal=node.journal,
                        bus=node.bus,
                    )
                )
                self.links.append(RobotLink(self, robot_node, body))
        except BaseException:
            self.close()
            raise

    def prefix(self, link: RobotLink) -> str:
        """What a log line about ``link`` starts with: its robot's name, in a fleet."""
        return f"{link.name}: " if self.fleet is not None else ""

    def present(self) -> int | None:
        """The stamp of the latest step published; None before the first."""
        return self.published_ns if self.published_ns >= 0 else None

    def _publish_state(self, final: bool) -> int:
        sim = self.sim
        tm_ns = sim.time_ns
        tm = Time.from_nanoseconds(tm_ns)
        self.published_ns = tm_ns
        every_step = self.node.recording_every_step
        for link in self.links:
            link.publish_state(sim.step_index, tm_ns, tm, every_step, final)
        return tm_ns

    def _final(self) -> bool:
        """Whether the state about to be published is a finite run's last (``--duration``): it is
        published, observed, and answered as any step's, then the run ends without stepping."""
        return self.sim.step_index >= self._end_step

    def _publish_clocks(self) -> None:
        for link in self.links:
            link.publish_clock()

    def _step(self) -> None:
        contacts = self.sim.step()
        if contacts:
            tm = Time.from_nanoseconds(self.sim.time_ns)
            for contact in contacts:
                self.links[contact.robot].bump(contact, tm)

    def _lockstep_torques(self, tm_ns: int, stop: threading.Event, final: bool) -> None:
        """Set this step's torque of every robot: its motor's answer for ``tm_ns``, or zero."""
        for link in self.links:
            link.begin_torque_wait(tm_ns)
        for link in self.links:
            self._lockstep_torque(link, tm_ns, stop, final)
        for link in self.links:
            link.end_torque_wait(final)

    def _lockstep_torque(self, link: RobotLink, tm_ns: int, stop: threading.Event, final: bool) -> None:
        """Wait for ``link``'s torque for ``tm_ns``; a torque that does not come counts as late or
        missing, but for the ``final`` state's, which is never applied."""
        if link.motor_alive:
            silent = link.motor_silent
            deadline = time.monotonic() + (self._silent_wait_s if silent else self.parameters.lockstep_timeout)
            spin_until = self.node.executor.spin_until  # the step's messages in one call, not one each
            settled = link.torque_settled
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    if settled():
                        return
                    if not silent:
                        link.late(tm_ns)
                    elif not final:
                        link.counters["missing_torques"] += 1
                    return
                if spin_until(settled, min(remaining, STOP_POLL_S), link.torque_input) or stop.is_set():
                    return
        else:
            self.node.drain()
            if not (link.answered or final):
                link.counters["missing_torques"] += 1

    def _lockstep_ticks(self, tm_ns: int, stop: threading.Event) -> None:
        """Wait for the outputs of the participants with a tick at ``tm_ns`` (or give up on them)."""
        due = []
        for link in self.links:  # a loop, not a comprehension: this runs at every step
            if link.barrier.ticks(tm_ns):
                due.append(link)
        if not due:
            return
        node = self.node
        deadline = time.monotonic() + self.parameters.lockstep_timeout
        for link in due:
            if link.motor_lost:
                for service in link.barrier.missing():
                    link.barrier.gave_up(service)
                continue
            while (missing := link.barrier.missing()) and not stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    for service in missing:
                        link.tick_timed_out(service, tm_ns)
                    break
                node.spin_once(min(remaining, STOP_POLL_S), link.outputs[missing[0]])

    def _ended(self) -> bool:
        if not self.until_drive_ends:
            return False
        for link in self.links:  # a loop, not all() over a generator: this runs at every step
            if not link.drive_ended:
                return False
        return True

    def _run_lockstep(self, stop: threading.Event) -> None:
        while not stop.is_set():
            final = self._final()
            tm_ns = self._publish_state(final)
            self._lockstep_torques(tm_ns, stop, final)
            self._publish_clocks()
            self._lockstep_ticks(tm_ns, stop)
            if final or self._ended():
                return
            self._step()

    def _run_realtime(self, stop: threading.Event) -> None:
        sim, node, links = self.sim, self.node, self.links
        period = sim.step_ns / NANOSECONDS_PER_SECOND / self.parameters.realtime_factor
        origin, origin_step = time.monotonic(), sim.step_index
        while not stop.is_set():
            final = self._final()
            tm_ns = self._publish_state(final)
            deadline = origin + (sim.step_index + 1 - origin_step) * period
            while (remaining := deadline - time.monotonic()) > 0.0:
                node.spin_once(min(remaining, STOP_POLL_S))
                for link in links:
                    if link.newest_ns == tm_ns:
                        link.publish_clock()
            self._publish_clocks()
            if final:
                return
            if -remaining > MAX_REALTIME_LAG_S:
                for link in links:
                    link.counters["realtime_resyncs"] += 1
                origin, origin_step = time.monotonic(), sim.step_index + 1
            node.drain()
            for link in links:
                link.realtime_torque(tm_ns, self._max_age_ns)
            if self._ended():
                return
            self._step()

    def run(self, stop: threading.Event) -> int:
        # Asked once at start, so the first steps already know whether to wait.
        for link in self.links:
            link.set_motor_alive(link.node.alive_now(Service.MOTOR))
        self.node.drain()
        self._await_services(stop)
        lockstep = self.mode == SimMode.LOCKSTEP
        if lockstep and any(link.motor_alive for link in self.links):
            self._await_motor_subscriptions()
        if lockstep:
            self._await_participants()
        self.node.log.info(
            "simulating %s in %s mode, step %g s%s%s",
            self.world_file,
            self.mode,
            self.parameters.step,
            "" if self.duration is None else f", for {self.duration:g} s",
            "" if self.fleet is None else f", robots {', '.join(link.name for link in self.links)}",
        )
        world = SimWorld(Time.from_nanoseconds(self.sim.time_ns), obstacles(self.world))
        for link in self.links:
            link.world_publisher.put(world)
        self._started_at = time.monotonic()
        self.started = True
        {SimMode.LOCKSTEP: self._run_lockstep, SimMode.REALTIME: self._run_realtime}[self.mode](stop)
        self.finished = self._final() or self._ended()
        self._stopped_at = time.monotonic()
        self.node.log.info("%s: %s", "finished" if self.finished else "stopped", self._summary())
        if self._ended():
            self.node.log.info("the drive's scenario ended: holding at this step until stopped")
            self.node.serve(stop, finished=lambda: False)
        return 0

    def _await_motor_subscriptions(self) -> None:
        """Give the first wheel angles a subscriber to reach, so the first step does not time out."""
        deadline = time.monotonic() + self.parameters.lockstep_timeout
        waiting = [link for link in self.links if link.motor_alive]
        while any(not link.angles_publisher.matched for link in waiting) and time.monotonic() < deadline:
            self.node.spin_once(STOP_POLL_S / 10.0)

    def _await_services(self, stop: threading.Event) -> None:
        """``--wait-for``: before the first step, until each named service of every robot is alive
        (a lockstep participant: holds its ticks token), so that the run starts the same way every time."""
        if not self.wait_for:
            return

        def missing() -> list[str]:
            return [
                f"{self.prefix(link)}{service}"
                for link in self.links
                for service in self.wait_for
                if not (link.motor_alive if service is Service.MOTOR else link.barrier.announced(service))
            ]

        deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S * len(self.links)
        while missing() and time.monotonic() < deadline and not stop.is_set():
            self.node.spin_once(STOP_POLL_S)
        if missing():
            self.node.log.warning(
                "starting without %s: not there within %g s",
                ", ".join(missing()),
                START_HANDSHAKE_TIMEOUT_S * len(self.links),
            )

    def _await_participants(self) -> None:
        """Before the first step, until each participant there from the start says it sees this
        simulator: a session this new has routes to a peer only once their declarations have
        crossed, and a participant that missed the first step's sample would miss its first tick.
        The thread keeps handling events meanwhile (composed, it serves those participants too)."""
        node = self.node
        deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S
        waiting = {
            (index, service)
            for index, link in enumerate(self.links)
            for service in (*link.barrier.waited_for(), *((Service.MOTOR,) if link.motor_alive else ()))
        }
        asked: dict[tuple[int, Service], Any] = {}
        while waiting and time.monotonic() < deadline:
            for index, service in waiting - set(asked):
                asked[index, service] = node.session.get(
                    self.links[index].node.keys.status(service), timeout=STOP_POLL_S
                )
            node.spin_once(STOP_POLL_S / 10.0)
            for participant, replies in list(asked.items()):
                try:
                    reply = replies.try_recv()
                except zenoh.ZError:  # unanswered within its timeout: asked again
                    del asked[participant]
                    continue
                if reply is None:
                    continue
                del asked[participant]  # answered: asked again unless it sees this simulator
                if reply.ok is not None and msgspec.json.decode(reply.ok.payload.to_bytes()).get("sim_alive"):
                    waiting.discard(participant)
        if waiting:
            names = sorted(f"{self.prefix(self.links[index])}{service}" for index, service in waiting)
            node.log.warning("%s did not see this simulator before its first step", ", ".join(names))

    def _elapsed(self) -> float:
        if self._started_at is None:
            return 0.0
        return (self._stopped_at if self._stopped_at is not None else time.monotonic()) - self._started_at

    def _steps_per_second(self) -> float:
        elapsed = self._elapsed()
        return self.sim.step_index / elapsed if elapsed > 0.0 else 0.0

    def _summary(self) -> str:
        sim = self.sim
        head = (
            f"{sim.step_index} steps, {sim.time_ns / NANOSECONDS_PER_SECOND:.3f} s simulated "
            f"in {self._elapsed():.3f} s ({self._steps_per_second():.0f} steps/s)"
        )
        if self.fleet is None:
            return f"{head}; {self.links[0].summary()}"
        return head + "".join(f"; {link.name}: {link.summary()}" for link in self.links)

    def world_status(self) -> dict[str, Any]:
        """The part of every robot's ``sim/status`` that is the world's."""
        sim = self.sim
        simulated = sim.time_ns / NANOSECONDS_PER_SECOND
        elapsed = self._elapsed()
        status: dict[str, Any] = {
            "state": "finished" if self.finished else ("running" if self.started else "starting"),
            "mode": self.mode,
            "world": str(self.world_file),
            "sim_time_s": simulated,
            "steps": sim.step_index,
            "steps_per_second": self._steps_per_second(),
            "realtime_factor_achieved": simulated / elapsed if elapsed > 0.0 else 0.0,
            "parameters": {
                "step": self.parameters.step,
                "observe_every": self.parameters.observe_every,
                "duration": self.duration,
                "lockstep_timeout": self.parameters.lockstep_timeout,
                "lockstep_max_late": self.parameters.lockstep_max_late,
                "realtime_factor": self.parameters.realtime_factor,
                "torque_max_age": self.parameters.torque_max_age,
                "brake_after": self.parameters.brake_after,
                "max_wheel_torque": self.parameters.max_wheel_torque,
            },
        }
        if self.fleet is not None:
            status["fleet"] = [link.name for link in self.links]
        return status

    def status(self) -> dict[str, Any]:
        return self.links[0].status()

    def close(self) -> None:
        for link in reversed(self.links):
            link.close()
            if link.node is not self.node:
                link.node.close()
        self.links.clear()
        self.sim.close()


COMMAND = ServiceCommand(service=Service.SIM, factory=SimService)
