"""Who is there for one robot of the sim bridge, from their liveliness tokens and outputs: its
motor control (``motor/alive``), the lockstep participants (``<service>/ticks/<rate>``) whose ticks
the steps wait at, the observers (``<service>/observes/<rate>``) whose steps are observed too, and
the drive's end. The link's zenoh callbacks hand each change over to the service thread, which
calls these: a lockstep wait in progress wakes for it, so a participant whose token goes is dropped
at once (named in the status's ``dropped_participants``)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from schemas.keys import Service, ServiceName
from schemas.messages import NANOSECONDS_PER_SECOND, TimedPosition, TimedVelocity
from schemas.status import DroppedParticipant
from schemas.tokens import parse_observes_key, parse_participant_key
from services.clock.lockstep import FINAL, MAX_PARTICIPANTS, OUTPUTS, StampedOutput, TickBarrier
from services.clock.observation import ObservedSteps
from services.config import SimConfig
from services.runtime.logs import RateLimitedLog
from sim_bridge.progress import RunProgress
from sim_bridge.torque_policy import TorquePolicy


@dataclass(kw_only=True)
class Liveness:
    """One robot's motor control, lockstep participants and observers as they come and go."""

    barrier: TickBarrier
    observation: ObservedSteps
    torque: TorquePolicy
    owed_changed: Callable[[], None]
    """Re-encodes the marks of the wheel angles: what the barrier owes has changed."""
    take_output: Callable[[ServiceName, str], None]
    """Subscribes a user participant's output (its key relative to the robot), once: a built-in's
    is subscribed from the start."""
    progress: RunProgress
    counters: dict[str, int]
    parameters: SimConfig
    log: logging.Logger
    warn: RateLimitedLog
    prefix: str
    motor_lost: bool = field(default=False, init=False)
    """Its motor control was alive and has gone: until one is back, nothing its participants
    command can move the robot, so the world does not wait at their ticks (in a fleet, the
    other robots go on at their pace)."""
    steps_over: bool = field(default=False, init=False)
    """The lockstep loop has stopped stepping: a participant that goes now (the run's end) is not dropped."""
    dropped: list[DroppedParticipant] = field(default_factory=list, init=False)
    """The participants whose token went while the lockstep run stepped and before their last
    output: ``{"service": name, "sim_time_s": the latest step's time}``, in order."""
    _long_wait_ns: int = field(default=-1, init=False)
    """The tick whose wait was last counted in ``long_waits``: counted once per tick."""
    drive_ended: bool = field(default=False, init=False)
    """The drive's last target (its scenario ended) has arrived, or the drive has gone: its token
    and its last target travel separately, and the token may come first."""

    def set_motor_alive(self, alive: bool) -> None:
        torque = self.torque
        if alive == torque.motor_alive:
            return
        self.motor_lost = torque.motor_alive and not alive
        torque.set_motor_alive(alive)
        if torque.silent:
            return  # said by the policy's event
        if alive:
            effect = "steps wait for its torques" if self.torque.lockstep else "applying its torques"
        else:
            effect = "stepping on with zero torque" if self.torque.lockstep else "zero torque"
        self.log.info("%smotor control %s: %s", self.prefix, "alive" if alive else "gone", effect)

    def participant_changed(self, key: str, alive: bool) -> None:
        parsed = parse_participant_key(key, OUTPUTS)
        if parsed is None:
            return
        service, rate_hz = parsed.service, parsed.rate_hz
        lockstep, prefix = self.torque.lockstep, self.prefix
        if alive:
            if not self.barrier.announce(service, rate_hz, from_start=not self.progress.started, output=parsed.output):
                self.counters["refused_participants"] += 1
                self.warn(
                    "refused_participant",
                    logging.WARNING,
                    "%s%s: not a lockstep participant: %d are already (the most one robot waits for)",
                    prefix,
                    service,
                    MAX_PARTICIPANTS,
                )
                return
            if not isinstance(service, Service):
                self.take_output(service, parsed.output)
            self.observation.add(key, rate_hz, self.progress.present())
            if lockstep:
                self.log.info("%s%s ticks at %g Hz: steps at its ticks wait for its output", prefix, service, rate_hz)
            return
        self.observation.remove(key)
        ended = self.barrier.final(service)
        if self.barrier.withdraw(service):
            self.owed_changed()
            if lockstep and not ended and self.progress.started and not self.steps_over:
                self._drop(service)
            elif lockstep:
                self.log.info("%s%s gone: its ticks are not waited for", prefix, service)
            if service is Service.DRIVE:
                self.drive_ended = True

    def _drop(self, service: ServiceName) -> None:
        t_s = max(self.progress.published_ns, 0) / NANOSECONDS_PER_SECOND
        self.dropped.append(DroppedParticipant(str(service), t_s))
        self.log.warning(
            "%s%s gone at t = %.3f s (its liveliness token): dropped, its ticks are not waited for",
            self.prefix,
            service,
            t_s,
        )

    def _ended_after_its_token(self, service: ServiceName) -> None:
        """A participant's last output came after its token had gone (they travel separately, and
        the token may come first): it ended, it was not dropped."""
        for index in range(len(self.dropped) - 1, -1, -1):
            if self.dropped[index].service == str(service):
                del self.dropped[index]
                self.log.info("%s%s had ended: its last output came after its token", self.prefix, service)
                return

    def observer_changed(self, key: str, alive: bool) -> None:
        parsed = parse_observes_key(key)
        if parsed is None:
            return
        service, rate_hz = parsed
        if alive:
            self.observation.add(key, rate_hz, self.progress.present())
            self.log.info("%s%s observes at %g Hz: those steps are observed too", self.prefix, service, rate_hz)
        else:
            self.observation.remove(key)

    def on_output(
        self, service: ServiceName, message: TimedVelocity | TimedPosition | StampedOutput, attachment: bytes | None
    ) -> None:
        final = attachment == FINAL
        if final:
            self._ended_after_its_token(service)
        self.barrier.took(service, message.tm.to_nanoseconds(), self.progress.published_ns, final=final)
        self.owed_changed()
        if final and service is Service.DRIVE and not self.drive_ended:
            self.drive_ended = True
            self.log.info("%sthe drive's scenario ended at t = %.3f s", self.prefix, message.tm.to_seconds())

    def still_waiting(self, missing: list[ServiceName], tm_ns: int, waited_s: float) -> None:
        """The tick at ``tm_ns`` has waited ``waited_s`` (another ``sim.lockstep_timeout``) for the
        outputs of ``missing``, whose tokens live: it waits on. Said (rate-limited), counted once
        per tick in ``long_waits``."""
        if tm_ns != self._long_wait_ns:
            self._long_wait_ns = tm_ns
            self.counters["long_waits"] += 1
        self.warn(
            "long_tick_wait",
            logging.WARNING,
            "%sstill waiting for %s for t = %.3f s after %.1f s: %s alive",
            self.prefix,
            ", ".join(self.barrier.output(service) for service in missing),
            tm_ns / NANOSECONDS_PER_SECOND,
            waited_s,
            "its token" if len(missing) == 1 else "their tokens",
        )
