"""``invent sim``: the PyBullet simulator bridge (docs/protocol.md section 6), a thin shell around the simulator core.

Every step publishes ``sim/wheel_angles`` stamped with simulation time, applies the wheel
torques and steps. The observed steps (services/clock/observation.py: every ``sim.observe_every``-th
step and each tick of a rate someone holds a token for) also publish ``sim/clock`` and
``sim/body_pose``; a recorded run publishes the body pose at every step. Each step's wheel angles
carry its :class:`~services.clock.lockstep.StepMark`: whether it is observed, and in lockstep
what it owes.

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

import argparse
import logging
import math
import threading
import time
from functools import partial
from typing import TYPE_CHECKING, Any

import msgspec
import zenoh

from schemas.codec import BadInput, encode
from schemas.keys import Method, MethodFamily, Service, parse_observes_key, parse_ticks_key
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
from services.config import Config, SimConfig, SimMode
from services.runtime.executor import STOP_POLL_S
from services.runtime.inputs import Delivery, NodeInput
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node
from services.service import ServiceCommand, positive_seconds
from sim_bridge.latency import TorqueLatency
from sim_bridge.world import DEFAULT_WORLD, builtin_worlds, obstacles, read_world, resolve_world

if TYPE_CHECKING:
    from sim_bridge.simulator import Contact

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
)
"""The counters of ``sim/status`` (docs/sim.md explains each)."""


class SimService:
    def __init__(self, node: Node, config: Config, args: argparse.Namespace) -> None:
        self.node = node
        self.parameters = config.sim
        self.mode = config.sim.mode
        self.duration: float | None = args.duration
        self.until_drive_ends: bool = args.until_drive_ends
        self.wait_for: list[Service] = args.wait_for or []
        self.drive_ended = False
        """The drive's last target (its scenario ended) has arrived, or the drive has gone: its token
        and its last target travel separately, and the token may come first."""
        self.barrier = TickBarrier()
        self._outputs: dict[Service, NodeInput | None] = {}
        """Lockstep: the participants' output channels, to wait in at their ticks."""
        self.observation = ObservedSteps(config.sim.observe_every)
        self._marks = (b"", b"")
        """The attachment of a step's wheel angles, (not observed, observed): what the barrier owes
        (in lockstep) and whether the step is observed. Encoded when they change, not at every step."""
        self._owed_changed()
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.motor_alive = False
        self.motor_silent = False
        """Alive but not answering: lockstep steps at real-time pace until its next torque."""
        self._late_in_a_row = 0
        self._silent_wait_s = config.sim.step / config.sim.realtime_factor
        self.finished = False
        self._started: float | None = None
        self._stopped_at: float | None = None
        self._awaited_ns = -1
        self._answered = False
        self._newest_torque: list[float] | None = None
        self._newest_ns = -1
        self._published_ns = -1
        """The stamp of the latest step published: no torque can answer a later one."""
        self._clock: tuple[TimedDoubleSeq, bytes] | None = None
        """(wheel angles, mark) of an observed step published, while its ``sim/clock`` waits."""
        self._max_age_ns = round(config.sim.torque_max_age * NANOSECONDS_PER_SECOND)
        self._warn = RateLimitedLog(node.log)
        # Imported here, not at the top: every `invent` command imports this module for its flags,
        # and importing PyBullet prints its build banner.
        from sim_bridge.simulator import Simulator

        self.world_file = resolve_world(config.sim.world)
        self.world = read_world(self.world_file)
        self.sim = Simulator(config.robot, config.sim, self.world, gui=args.gui)
        self.latency = TorqueLatency(self.sim.step_ns)
        self._end_step = (
            math.inf if args.duration is None else round(args.duration * NANOSECONDS_PER_SECOND / self.sim.step_ns)
        )
        try:
            self._declare()
        except BaseException:
            self.sim.close()
            raise

    def _declare(self) -> None:
        node, keys = self.node, self.node.keys
        self._pose_publisher = node.publisher(keys.sim_body_pose)
        self._angles_publisher = node.publisher(keys.sim_wheel_angles)
        self._clock_publisher = node.publisher(keys.sim_clock)
        self._bump_publisher = node.publisher(keys.sim_bump)
        self._world_publisher = node.latched_publisher(keys.sim_world)
        # Lockstep waits in the torque channel's receive itself, and in a participant's output
        # channel at its ticks; realtime waits for its step's deadline, which a posted torque must
        # interrupt.
        lockstep = self.mode == SimMode.LOCKSTEP
        delivery = Delivery.EVERY if lockstep else Delivery.QUEUED
        node.subscribe(keys.motor_torque, TimedDoubleSeq, self._on_torque, delivery, wakes=lockstep)
        for service, message_type in ((Service.DRIVE, TimedVelocity), (Service.LOCALIZATION, TimedPosition)):
            self._outputs[service] = node.subscribe(
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
        node.watch(Service.MOTOR, self._set_motor_alive)
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

    def _set_motor_alive(self, alive: bool) -> None:
        if alive == self.motor_alive:
            return
        self.motor_alive = alive
        self._set_motor_silent(False)
        lockstep = self.mode == SimMode.LOCKSTEP
        if alive:
            effect = "steps wait for its torques" if lockstep else "applying its torques"
        else:
            effect = "stepping on with zero torque" if lockstep else "zero torque"
        self.node.log.info("motor control %s: %s", "alive" if alive else "gone", effect)

    def _set_motor_silent(self, silent: bool) -> None:
        self._late_in_a_row = 0
        if silent == self.motor_silent:
            return
        self.motor_silent = silent
        if silent:
            self.node.log.warning(
                "motor control alive but silent for %d steps: stepping at real-time pace until it answers",
                self.parameters.lockstep_max_late,
            )
        elif self.motor_alive:
            self.node.log.info("motor control answers again: steps wait for its torques")

    def _participant_changed(self, key: str, alive: bool) -> None:
        parsed = parse_ticks_key(key)
        if parsed is None or parsed[0] not in OUTPUTS:
            return
        service, rate_hz = parsed
        if alive:
            self.observation.add(key, rate_hz, self._present())
            self.barrier.announce(service, rate_hz, from_start=self._started is None)
            if self.mode == SimMode.LOCKSTEP:
                self.node.log.info("%s ticks at %g Hz: steps at its ticks wait for its output", service, rate_hz)
            return
        self.observation.remove(key)
        if self.barrier.withdraw(service):
            self._owed_changed()
            if self.mode == SimMode.LOCKSTEP:
                self.node.log.info("%s gone: its ticks are not waited for", service)
            if service is Service.DRIVE:
                self.drive_ended = True

    def _observer_changed(self, key: str, alive: bool) -> None:
        parsed = parse_observes_key(key)
        if parsed is None:
            return
        service, rate_hz = parsed
        if alive:
            self.observation.add(key, rate_hz, self._present())
            self.node.log.info("%s observes at %g Hz: those steps are observed too", service, rate_hz)
        else:
            self.observation.remove(key)

    def _present(self) -> int | None:
        """The stamp of the latest step published; None before the first."""
        return self._published_ns if self._published_ns >= 0 else None

    def _on_output(self, service: Service, message: TimedVelocity | TimedPosition, attachment: bytes | None) -> None:
        final = attachment == FINAL
        self.barrier.took(service, message.tm.to_nanoseconds(), self._published_ns, final=final)
        self._owed_changed()
        if final and service is Service.DRIVE and not self.drive_ended:
            self.drive_ended = True
            self.node.log.info("the drive's scenario ended at t = %.3f s", message.tm.to_seconds())

    def _record_bump_stop_reply(self, ok: bool, reason: str) -> None:
        if ok:
            self.counters["bump_stop_acks"] += 1
        else:
            self.counters["bump_stop_errors"] += 1
            self.node.log.warning("motor/bump/stop answered with an error: %s", reason)

    def _on_torque(self, torque: TimedDoubleSeq) -> None:
        if len(torque.data) != self.sim.wheel_count:
            raise BadInput(f"{len(torque.data)} torques, expected {self.sim.wheel_count} (one per wheel id)")
        tm_ns = torque.tm.to_nanoseconds()
        self.latency.answered(tm_ns, time.perf_counter_ns())
        if self.mode == SimMode.LOCKSTEP:
            if self.motor_silent:
                self._set_motor_silent(False)
            if tm_ns != self._awaited_ns or self._answered:
                self.counters["stale_torques"] += 1
                return
            self.sim.set_torques(torque.data)
            self._answered = True
        elif tm_ns > self._published_ns:
            raise BadInput(
                f"torque stamped t = {tm_ns / NANOSECONDS_PER_SECOND:.6f} s, after the latest step "
                f"(t = {self._published_ns / NANOSECONDS_PER_SECOND:.6f} s): from the future"
            )
        elif tm_ns > self._newest_ns:
            self._newest_torque, self._newest_ns = torque.data, tm_ns

    def _publish_state(self) -> int:
        """Publish this step's wheel angles, then its body pose if it is observed (or recorded):
        the motor converts the pose once it has answered the wheel angles, in the same wake. The
        step's clock waits for :meth:`_publish_clock`."""
        sim = self.sim
        tm_ns = sim.time_ns
        observed = self.observation.observed(sim.step_index, tm_ns)
        mark = self._marks[observed]
        tm = Time.from_nanoseconds(tm_ns)
        angles = TimedDoubleSeq(tm=tm, data=sim.wheel_angles())
        self.latency.published(tm_ns, time.perf_counter_ns())
        self._published_ns = tm_ns
        self._angles_publisher.put(angles, mark)
        if observed or self.node.recording:
            self._pose_publisher.put(TimedDoubleSeq(tm=tm, data=sim.body_pose()), mark)
        if observed:
            self._clock = (angles, mark)
        return tm_ns

    def _publish_clock(self) -> None:
        """Publish this step's ``sim/clock`` if it is observed, once the step's torque is in or its
        wait is over: the drive's command (and the ROS 2 bridge's messages) are then computed while
        the simulator steps, not while the motor computes the torque."""
        pending, self._clock = self._clock, None
        if pending is not None:
            self._clock_publisher.put(*pending)

    def _step(self) -> None:
        for contact in self.sim.step():
            self._bump(contact)

    def _bump(self, contact: Contact) -> None:
        self.counters["bumps"] += 1
        tm = Time.from_nanoseconds(self.sim.time_ns)
        self.node.log.info(
            "bump: began touching %r at (%.3f, %.3f, %.3f), t = %.3f s; calling motor/bump/stop",
            contact.obstacle,
            contact.x,
            contact.y,
            contact.z,
            tm.to_seconds(),
        )
        self._bump_publisher.put(BumpEvent(tm=tm, obstacle=contact.obstacle, x=contact.x, y=contact.y, z=contact.z))
        self.counters["bump_stop_calls"] += 1
        self._bump_stop.get(self._on_bump_stop_reply, payload=_BUMP_STOP_PAYLOAD)

    def _lockstep_torque(self, tm_ns: int, stop: threading.Event) -> None:
        """Set this step's torque: the motor's answer for ``tm_ns``, or zero."""
        node, counters = self.node, self.counters
        self._awaited_ns, self._answered = tm_ns, False
        if self.motor_alive:
            silent = self.motor_silent
            deadline = time.monotonic() + (self._silent_wait_s if silent else self.parameters.lockstep_timeout)
            while not self._answered and self.motor_alive and not stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    if silent:
                        counters["missing_torques"] += 1
                    else:
                        self._late(tm_ns)
                    break
                node.spin_once(min(remaining, STOP_POLL_S))
        else:
            node.drain()
            if not self._answered:
                counters["missing_torques"] += 1
        self._awaited_ns = -1
        if self._answered:
            self._late_in_a_row = 0
            counters["torques_applied"] += 1
        else:
            self.sim.set_zero_torques()

    def _late(self, tm_ns: int) -> None:
        self.counters["late_torques"] += 1
        self._warn(
            "late_torque",
            logging.WARNING,
            "no motor/torque for t = %.3f s within %.3f s: zero torque",
            tm_ns / NANOSECONDS_PER_SECOND,
            self.parameters.lockstep_timeout,
        )
        self._late_in_a_row += 1
        if self._late_in_a_row >= self.parameters.lockstep_max_late:
            self._set_motor_silent(True)

    def _lockstep_ticks(self, tm_ns: int, stop: threading.Event) -> None:
        """Wait for the outputs of the participants with a tick at ``tm_ns`` (or give up on them)."""
        barrier, node = self.barrier, self.node
        if barrier.ticks(tm_ns):
            deadline = time.monotonic() + self.parameters.lockstep_timeout
            while (missing := barrier.missing()) and not stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    for service in missing:
                        barrier.gave_up(service)
                        self.counters["tick_timeouts"] += 1
                        self._warn(
                            f"tick_timeout_{service}",
                            logging.WARNING,
                            "no %s for t = %.3f s within %.3f s: stepping on; waiting for it again once it outputs",
                            OUTPUTS[service],
                            tm_ns / NANOSECONDS_PER_SECOND,
                            self.parameters.lockstep_timeout,
                        )
                    break
                node.spin_once(min(remaining, STOP_POLL_S), self._outputs[missing[0]])

    def _owed_changed(self) -> None:
        owed = self.barrier.owed() if self.mode == SimMode.LOCKSTEP else None
        self._marks = (encode_mark(owed, observed=False), encode_mark(owed, observed=True))

    def _ended(self) -> bool:
        return self.until_drive_ends and self.drive_ended

    def _run_lockstep(self, stop: threading.Event) -> None:
        sim = self.sim
        while sim.step_index < self._end_step and not stop.is_set():
            tm_ns = self._publish_state()
            self._lockstep_torque(tm_ns, stop)
            self._publish_clock()
            self._lockstep_ticks(tm_ns, stop)
            if self._ended():
                return
            self._step()

    def _realtime_torque(self, tm_ns: int) -> None:
        if self._newest_ns != tm_ns:
            self.counters["realtime_late_steps"] += 1
        newest = self._newest_torque
        if newest is not None and 0 <= tm_ns - self._newest_ns <= self._max_age_ns:
            self.sim.set_torques(newest)
            self.counters["torques_applied"] += 1
        else:
            self.sim.set_zero_torques()
            self.counters["missing_torques"] += 1

    def _run_realtime(self, stop: threading.Event) -> None:
        sim, node = self.sim, self.node
        period = sim.step_ns / NANOSECONDS_PER_SECOND / self.parameters.realtime_factor
        origin, origin_step = time.monotonic(), sim.step_index
        while sim.step_index < self._end_step and not stop.is_set():
            tm_ns = self._publish_state()
            deadline = origin + (sim.step_index + 1 - origin_step) * period
            while (remaining := deadline - time.monotonic()) > 0.0:
                node.spin_once(min(remaining, STOP_POLL_S))
                if self._newest_ns == tm_ns:
                    self._publish_clock()
            self._publish_clock()
            if -remaining > MAX_REALTIME_LAG_S:
                self.counters["realtime_resyncs"] += 1
                origin, origin_step = time.monotonic(), sim.step_index + 1
            node.drain()
            self._realtime_torque(tm_ns)
            if self._ended():
                return
            self._step()

    def run(self, stop: threading.Event) -> int:
        # Asked once at start, so the first steps already know whether to wait.
        self._set_motor_alive(self.node.alive_now(Service.MOTOR))
        self.node.drain()
        self._await_services(stop)
        if self.motor_alive and self.mode == SimMode.LOCKSTEP:
            self._await_motor_subscription()
        if self.mode == SimMode.LOCKSTEP:
            self._await_participants()
        self.node.log.info(
            "simulating %s in %s mode, step %g s%s",
            self.world_file,
            self.mode,
            self.parameters.step,
            "" if self.duration is None else f", for {self.duration:g} s",
        )
        self._world_publisher.put(SimWorld(Time.from_nanoseconds(self.sim.time_ns), obstacles(self.world)))
        self._started = time.monotonic()
        {SimMode.LOCKSTEP: self._run_lockstep, SimMode.REALTIME: self._run_realtime}[self.mode](stop)
        self.finished = self.sim.step_index >= self._end_step or self._ended()
        self._stopped_at = time.monotonic()
        self.node.log.info("%s: %s", "finished" if self.finished else "stopped", self._summary())
        if self._ended():
            self.node.log.info("the drive's scenario ended: holding at this step until stopped")
            self.node.serve(stop, finished=lambda: False)
        return 0

    def _await_motor_subscription(self) -> None:
        """Give the first wheel angles a subscriber to reach, so the first step does not time out."""
        deadline = time.monotonic() + self.parameters.lockstep_timeout
        while not self._angles_publisher.matched and time.monotonic() < deadline:
            self.node.spin_once(STOP_POLL_S / 10.0)

    def _await_services(self, stop: threading.Event) -> None:
        """``--wait-for``: before the first step, until each named service is alive (a lockstep
        participant: holds its ticks token), so that the run starts the same way every time."""
        if not self.wait_for:
            return

        def missing() -> list[str]:
            return [
                str(service)
                for service in self.wait_for
                if not (self.motor_alive if service is Service.MOTOR else self.barrier.announced(service))
            ]

        deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S
        while missing() and time.monotonic() < deadline and not stop.is_set():
            self.node.spin_once(STOP_POLL_S)
        if missing():
            self.node.log.warning(
                "starting without %s: not there within %g s", ", ".join(missing()), START_HANDSHAKE_TIMEOUT_S
            )

    def _await_participants(self) -> None:
        """Before the first step, until each participant there from the start says it sees this
        simulator: a session this new has routes to a peer only once their declarations have
        crossed, and a participant that missed the first step's sample would miss its first tick.
        The thread keeps handling events meanwhile (composed, it serves those participants too)."""
        node = self.node
        deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S
        waiting = set(self.barrier.waited_for()) | ({Service.MOTOR} if self.motor_alive else set())
        asked: dict[Service, Any] = {}
        while waiting and time.monotonic() < deadline:
            for service in waiting - set(asked):
                asked[service] = node.session.get(node.keys.status(service), timeout=STOP_POLL_S)
            node.spin_once(STOP_POLL_S / 10.0)
            for service, replies in list(asked.items()):
                try:
                    reply = replies.try_recv()
                except zenoh.ZError:  # unanswered within its timeout: asked again
                    del asked[service]
                    continue
                if reply is None:
                    continue
                del asked[service]  # answered: asked again unless it sees this simulator
                if reply.ok is not None and msgspec.json.decode(reply.ok.payload.to_bytes()).get("sim_alive"):
                    waiting.discard(service)
        if waiting:
            node.log.warning("%s did not see this simulator before its first step", ", ".join(sorted(waiting)))

    def _elapsed(self) -> float:
        if self._started is None:
            return 0.0
        return (self._stopped_at if self._stopped_at is not None else time.monotonic()) - self._started

    def _steps_per_second(self) -> float:
        elapsed = self._elapsed()
        return self.sim.step_index / elapsed if elapsed > 0.0 else 0.0

    def _planar_pose(self) -> dict[str, float]:
        x, y, _z, r00, _r01, _r02, r10 = self.sim.body_pose()[:7]
        return {"x": x, "y": y, "theta": math.atan2(r10, r00)}

    def _summary(self) -> str:
        sim = self.sim
        pose = self._planar_pose()
        counters = ", ".join(f"{name} {count}" for name, count in self.counters.items())
        return (
            f"{sim.step_index} steps, {sim.time_ns / NANOSECONDS_PER_SECOND:.3f} s simulated "
            f"in {self._elapsed():.3f} s "
            f"({self._steps_per_second():.0f} steps/s); {counters}; "
            f"pose x {pose['x']:.4f} m, y {pose['y']:.4f} m, theta {pose['theta']:.4f} rad"
        )

    def status(self) -> dict[str, Any]:
        sim = self.sim
        simulated = sim.time_ns / NANOSECONDS_PER_SECOND
        elapsed = self._elapsed()
        return {
            "state": "finished" if self.finished else ("running" if self._started is not None else "starting"),
            "mode": self.mode,
            "world": str(self.world_file),
            "motor_alive": self.motor_alive,
            "motor_silent": self.motor_silent,
            "sim_time_s": simulated,
            "steps": sim.step_index,
            "steps_per_second": self._steps_per_second(),
            "realtime_factor_achieved": simulated / elapsed if elapsed > 0.0 else 0.0,
            "torques": list(sim.applied_torques),
            "pose": self._planar_pose(),
            "counters": dict(self.counters),
            "torque_latency": self.latency.summary(),
            "late_fraction": self._late_fraction(),
            "lockstep_participants": self.barrier.status(),
            "observed_steps": self.observation.count,
            "observed_rates": self.observation.rates(),
            "drive_ended": self.drive_ended,
            "parameters": {
                "step": self.parameters.step,
                "observe_every": self.parameters.observe_every,
                "duration": self.duration,
                "lockstep_timeout": self.parameters.lockstep_timeout,
                "lockstep_max_late": self.parameters.lockstep_max_late,
                "realtime_factor": self.parameters.realtime_factor,
                "torque_max_age": self.parameters.torque_max_age,
                "max_wheel_torque": self.parameters.max_wheel_torque,
            },
        }

    def _late_fraction(self) -> float:
        """Steps whose torque came late: past the timeout (lockstep), after the step (realtime)."""
        late = self.counters["late_torques" if self.mode == SimMode.LOCKSTEP else "realtime_late_steps"]
        return late / self.sim.step_index if self.sim.step_index else 0.0

    def close(self) -> None:
        self._ticks_watch.undeclare()
        self._observers_watch.undeclare()
        self._bump_stop.undeclare()
        self.sim.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = SimConfig()
    group = parser.add_argument_group("simulation")
    group.add_argument("--mode", choices=list(SimMode), help=f"(default {defaults.mode})")
    group.add_argument(
        "--step", type=positive_seconds, metavar="S", help=f"simulated seconds per step (default {defaults.step:g})"
    )
    group.add_argument("--duration", type=positive_seconds, metavar="S", help="simulate S seconds, then exit 0")
    group.add_argument(
        "--wait-for",
        nargs="+",
        type=Service,
        choices=[service for service in Service if service is not Service.SIM],
        metavar="SERVICE",
        help=f"before the first step, wait (at most {START_HANDSHAKE_TIMEOUT_S:g} s) until these services are there "
        "(motor: alive; drive, localization: holding their lockstep token), so a lockstep run starts the same way "
        "every time (invent up uses it)",
    )
    group.add_argument(
        "--until-drive-ends",
        action="store_true",
        help="stop stepping at the drive's last target (the end of its scenario) and hold there, answering "
        "status, until stopped: a lockstep run then ends at the same step every time (invent up uses it)",
    )
    group.add_argument(
        "--realtime-factor",
        type=positive_seconds,
        metavar="F",
        help=f"realtime mode: simulated seconds per wall second (default {defaults.realtime_factor:g})",
    )
    group.add_argument(
        "--world",
        metavar="FILE",
        help=f"world TOML file, or a built-in world ({', '.join(builtin_worlds())}); default: {DEFAULT_WORLD}",
    )
    group.add_argument("--gui", action="store_true", help="open a PyBullet window (needs a display)")


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "sim.mode": args.mode,
        "sim.step": args.step,
        "sim.realtime_factor": args.realtime_factor,
        "sim.world": args.world,
    }


COMMAND = ServiceCommand(
    service=Service.SIM,
    help="the PyBullet simulator: wheel angles and body pose out, wheel torques in",
    description="Plays OpenHRP3 and its controller bridge with PyBullet: each step publishes sim/wheel_angles and "
    "sim/body_pose stamped with simulation time, applies the motor/torque answer and steps. Lockstep (default) "
    "waits for the torque of each step while a motor control is alive; realtime paces steps to the wall clock. "
    "A contact with an obstacle publishes sim/bump and calls motor/bump/stop. Parameters: [robot] geometry and "
    "[sim] in the robot description; worlds are TOML files (docs/sim.md).",
    add_arguments=add_arguments,
    overrides=overrides,
    factory=SimService,
)
