"""A driving user service's side of the loop (docs/extending.md, A service that drives): it runs as
the drive (its node is the drive's: ``drive/alive``, ``drive/status``), publishes
``drive/target_velocity`` at the ticks its :class:`~services.extension.driving.DrivingCore` says,
holds the drive's ticks token once the motor subscribes, follows ``motor/state`` and ``sim/bump`` for
the give-up rule, and ends as the drive does: its last zero marked final, then ``drive/outcome``."""

from __future__ import annotations

from collections.abc import Callable

from schemas.drive_status import DriveOutcome, DriveStatus
from schemas.messages import BumpEvent, MotorStateReport, ScenarioOutcome, Time, TimedVelocity
from schemas.status import Velocity
from services.clock.lockstep import FINAL
from services.config import Config
from services.extension.driving import DrivingCore
from services.runtime.inputs import Delivery
from services.runtime.node import Node


class DriveOutput:
    """The velocity output of a service that drives, at ``rate_hz``; ``on_end(exit_code)`` once its
    outcome is out (the outcome's exit code: services/drive/outcome.py)."""

    def __init__(self, node: Node, config: Config, name: str, rate_hz: float, on_end: Callable[[int], None]) -> None:
        self.name = name
        self.core = DrivingCore(config.drive, rate_hz)
        self._on_end = on_end
        keys = node.keys
        self.publisher = node.publisher(keys.drive_target_velocity)
        self._outcome = node.latched_publisher(keys.drive_outcome)
        self.motor_state = ""
        node.subscribe_latched(keys.motor_state, MotorStateReport, self._on_motor_state)
        node.subscribe(keys.sim_bump, BumpEvent, self._on_bump, Delivery.QUEUED)
        node.participate(self.publisher, rate_hz)
        self._node = node

    def drive(self, stamp: Time, vx: float, w: float) -> bool:
        """Publish ``(vx, w)``, limited, stamped ``stamp``, if ``stamp`` takes the next tick (True)."""
        if not self.publisher.matched:
            return False  # nobody listens yet: the ticks start once the motor does, as the drive's
        tick = self.core.tick(stamp.to_nanoseconds(), vx, w)
        if tick is None:
            return False
        command = tick.command
        tm = Time.from_nanoseconds(tick.stamp_ns)
        self.publisher.put(
            TimedVelocity(tm=tm, id=[], vx=command.vx, vy=0.0, w=command.w, error=[]), FINAL if tick.final else None
        )
        if tick.outcome is not None:
            outcome = tick.outcome
            self._outcome.put(
                ScenarioOutcome(
                    tm=tm,
                    scenario=self.name,
                    outcome=outcome.outcome.value,
                    reason=outcome.reason,
                    iteration=0,
                    elapsed_s=self.core.elapsed_s,
                )
            )
            self._node.log.info("%s: %s %s", self.name, outcome.outcome, outcome.reason)
            self._on_end(outcome.outcome.exit_code)
        return True

    def _on_motor_state(self, report: MotorStateReport) -> None:
        self.motor_state = report.state
        self.core.give_up.motor_state(report.state, report.tm.to_nanoseconds(), report.stopped_by, report.held_by)

    def _on_bump(self, bump: BumpEvent) -> None:
        self.core.give_up.bump(bump.obstacle, bump.tm.to_nanoseconds())

    def status(self, sim_alive: bool) -> DriveStatus:
        """The drive's status fields that a run's report and the sim's start handshake read
        (``sim_alive``: the runtime's)."""
        core, give_up = self.core, self.core.give_up
        outcome = core.outcome
        return DriveStatus(
            state="done" if core.done else "ending" if outcome is not None else "running",
            mode="user_service",
            driven_by=self.name,
            rate_hz=core.rate_hz,
            commands_published=core.commands,
            command=Velocity(core.command.vx, core.command.w),
            lockstep_participant=self._node.participating,
            time_base_restarts=core.restarts,
            sim_alive=sim_alive,
            motor_state=self.motor_state,
            motor_held_by=give_up.held_by,
            motor_stopped_since_s=give_up.stopped_since_s,
            motor_held_since_s=give_up.held_since_s,
            outcome=None if outcome is None else DriveOutcome(str(outcome.outcome), outcome.reason),
            elapsed_s=core.elapsed_s,
        )
