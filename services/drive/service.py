"""``invent drive``: the velocity source (the seed's DriveControlRTC), docs/protocol.md section 7.

Publishes ``drive/target_velocity`` at ``drive.rate`` per second of simulation time. The clock is the
stamps on ``sim/clock`` (the simulator's observed steps, among them each tick: docs/protocol.md section
2.7): the ticks are the grid ``round(k·1e9/rate)`` ns, each taken by the first stamp at or after it;
scenario time starts at the first stamp once the motor subscribes, and a command is stamped with the
stamp that took its tick. It publishes the path it plans on ``drive/path`` (latched). Waypoint segments
close the loop on ``odometry/pose`` (reset by every ``localization/pose`` fix). Both inputs are sampled
(:attr:`~services.runtime.inputs.Delivery.SAMPLED`): the newest clock stamp and pose, never a backlog.

The drive is a lockstep participant (services/clock/lockstep.py): once the motor subscribes it holds
the token ``drive/ticks/<rate>``, and in lockstep (the clock's samples carry the simulator's
attachment) a tick's command is computed from the odometry pose stamped with that tick, waited
for as long as odometry is alive and in step (one that came back mid-run: at most
``sim.lockstep_timeout`` of wall time, until it gives a tick's pose in time).

When the scenario ends the drive publishes zero velocity on :data:`FINAL_ZERO_TICKS`
successive ticks, so the stop is not lost, the last with the attachment
:data:`~services.clock.lockstep.FINAL`, then its outcome on ``drive/outcome`` (latched), and exits
with the outcome's code (services/drive/outcome.py): 0 ``completed``; 3 ``aborted``, the motor latched
stopped (``sim/bump`` names what it bumped into) or held by its collision monitor (``held_by``) for
``drive.give_up_after_stop``; 4 ``timed_out``, a pass past the scenario's time limit. A ``--twist``
holds its target until Ctrl-C and gives nothing up.

A restarted simulator (its token appears, its clock goes back) starts the scenario over: a new run.

In goal mode (``--goals``, ``--goal-file``; services/drive/goal_shell.py) there is no scenario and
no planned path: the drive answers ``drive/goal/send`` and ``drive/goal/cancel``, commands zero
between goals, and a goal file's run ends as a scenario does, with its last goal's outcome. With
``navigation.enabled`` (services/drive/navigation_shell.py) it keeps a costmap from ``sim/scan`` (and a
map), and each goal navigates on it (services/navigation/): ``drive/map``, ``drive/costmap``, ``drive/plan``.
"""

from __future__ import annotations

import math
import time

import msgspec

from schemas.drive_status import DriveOutcome, DriveStatus
from schemas.keys import Service
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    BumpEvent,
    MotorStateReport,
    PlannedPath,
    ScenarioOutcome,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.status import PlanarPose, Velocity
from services.clock.lockstep import FINAL, decode_owed
from services.clock.sim_time import PeriodicSchedule, StampClock, check_stamp_near
from services.clock.sim_watch import SimulatorWatch
from services.config import Config
from services.drive.goal_shell import GoalDrive
from services.drive.navigation_shell import NavigationShell
from services.drive.options import GOALS_MODE, DriveOptions, check
from services.drive.outcome import GiveUp, GiveUpRule, Outcome, time_limit
from services.drive.path_following import STOPPED, Command
from services.drive.scenarios import (
    ScenarioRunner,
    describe,
    is_builtin,
    placed,
    planned_path,
)
from services.planar import Pose, check_coordinates
from services.runtime.inputs import Delivery
from services.runtime.node import Node, Wait
from services.service import ServiceCommand

FINAL_ZERO_TICKS = 3
"""Ticks on which the final zero velocity is published before the drive exits."""
TWIST_PASS_S = 1.0
"""``--twist``: the constant segment played over and over (its path is this much of the arc ahead)."""


class DriveService:
    def __init__(self, node: Node, config: Config, options: DriveOptions) -> None:
        self.node = node
        self.rate_hz = config.drive.rate
        self.pose_timeout_ns = round(config.drive.pose_timeout * NANOSECONDS_PER_SECOND)
        self.mode, scenario, loop = options.mode, options.scenario, options.loop
        odometry = config.odometry
        start = Pose(odometry.initial_x, odometry.initial_y, odometry.initial_theta)
        # A built-in scenario runs from where the robot starts, as the odometry does.
        self.runner = (
            None
            if scenario is None
            else ScenarioRunner(placed(scenario, start) if is_builtin(scenario) else scenario, config.drive, loop=loop)
        )
        # A target held by hand (--twist) runs until Ctrl-C: nothing to give up. A goal's limit is its own.
        self.give_up = GiveUpRule(
            config.drive if self.mode != "twist" else msgspec.structs.replace(config.drive, give_up_after_stop=None),
            None
            if self.mode == "twist" or self.runner is None
            else time_limit(self.runner.scenario, start, config.drive),
        )
        self.outcome: GiveUp | None = None
        """How the scenario ended, once it has (completed, or given up); in goal mode, the last goal."""
        self.clock = StampClock(config.input.stamp_horizon_ns)
        self.max_coordinate = config.input.max_coordinate
        self.schedule: PeriodicSchedule | None = None
        self.pose: Pose | None = None
        self.pose_stamp_ns: int | None = None
        self.commands_published = 0
        self.final_zeros = 0
        self._pass_elapsed_s = 0.0
        self.finished = False
        self.odometry_alive = False
        self.odometry_in_step = False
        """Odometry was there before the first tick, or has since given a tick's pose in time: a
        tick's pose is then waited for as long as odometry lives (said every ``pose_wait_s``). One
        that came back mid-run may hold its poses for a fix it missed: waited for ``pose_wait_s``."""
        self.pose_wait_s = config.sim.lockstep_timeout
        self.pose_wait_timeouts = 0
        """Lockstep ticks whose pose did not come within ``pose_wait_s``: computed from an older one."""
        self._pending_tick: tuple[int, float] | None = None
        """Lockstep: (tick stamp, wall deadline) of a tick waiting for the odometry pose of its stamp."""
        self.publisher = node.publisher(node.keys.drive_target_velocity)
        self._path = node.latched_publisher(node.keys.drive_path)
        self._outcome = node.latched_publisher(node.keys.drive_outcome)
        self.motor_stopped_by: str | None = None
        """Who latched the motor's stop (``motor/state``'s ``stopped_by``) while it is latched; else None."""
        self.navigation = (
            NavigationShell(node, config) if self.mode == GOALS_MODE and config.navigation.enabled else None
        )
        """Goals navigate on a costmap (docs/navigation.md); None: scenarios, or goals along the straight line."""
        self.goal_drive = (
            GoalDrive(
                node,
                config,
                options.goal_file,
                self.give_up,
                lambda: self.pose if self.clock.last_ns is None else self._fresh_pose(self.clock.last_ns),
                lambda: self.motor_stopped_by,
                None if self.navigation is None else self.navigation.costmap,
            )
            if self.mode == GOALS_MODE
            else None
        )
        node.subscribe_latched(node.keys.motor_state, MotorStateReport, self._on_motor_state)
        node.subscribe(node.keys.sim_bump, BumpEvent, self._on_bump, Delivery.QUEUED)
        self.sim = sim = SimulatorWatch(node, self.clock.restart)
        self._clock_input = node.subscribe(
            node.keys.sim_clock,
            TimedDoubleSeq,
            sim.clock(self._on_clock),
            Delivery.SAMPLED,
            with_attachment=True,
        )
        self._pose_input = node.subscribe(
            node.keys.odometry_pose,
            TimedPosition,
            sim.stamped(node.keys.odometry_pose, self._on_pose, awaited=lambda: self._pending_tick is not None),
            Delivery.SAMPLED,
        )
        node.watch(Service.ODOMETRY, self._on_odometry_liveliness)
        node.participate(self.publisher, self.rate_hz)
        node.wait_with(self._next_wait)
        node.set_status(self.status)
        if scenario is not None:
            node.log.info(
                "%s %r%s at %g Hz of simulation time:\n%s",
                self.mode,
                scenario.name,
                " (looping)" if loop else "",
                self.rate_hz,
                describe(scenario),
            )
        else:
            node.log.info(
                "goals at %g Hz of simulation time: %s",
                self.rate_hz,
                f"from {options.goal_file.name!r}, and from {node.keys.drive_goal_send}"
                if options.goal_file is not None
                else f"send them to {node.keys.drive_goal_send} (invent goto X Y [THETA])",
            )

    @property
    def state(self) -> str:
        if self.finished or (self.runner is not None and self.runner.done):
            return "done"
        if self.schedule is None:
            return "waiting_for_clock" if self.clock.last_ns is None else "waiting_for_subscriber"
        if self.runner is None:
            return "waiting_for_goal" if self.goal_drive is not None and self.goal_drive.goals.idle else "running"
        return "waiting_for_pose" if self.runner.waiting_for_pose else "running"

    @property
    def exit_code(self) -> int:
        """The outcome's exit code once the drive has finished (services/drive/outcome.py)."""
        return self.outcome.outcome.exit_code if self.finished and self.outcome is not None else 0

    def _on_motor_state(self, report: MotorStateReport) -> None:
        self.motor_stopped_by = report.stopped_by if report.state == "stopped" else None
        self.give_up.motor_state(report.state, report.tm.to_nanoseconds(), report.stopped_by, report.held_by)

    def _on_bump(self, bump: BumpEvent) -> None:
        self.give_up.bump(bump.obstacle, bump.tm.to_nanoseconds())

    def _on_odometry_liveliness(self, alive: bool) -> None:
        self.odometry_alive = alive
        self.odometry_in_step = alive and self.schedule is None
        if not alive:
            self._complete_tick()

    def _on_pose(self, message: TimedPosition) -> None:
        check_coordinates(message.x, message.y, self.max_coordinate)
        if self.clock.last_ns is not None:
            # An old pose is only stale (odometry stopped: _fresh_pose ignores it); one from
            # beyond the horizon is bad input.
            check_stamp_near(message.tm.to_nanoseconds(), self.clock.last_ns, self.clock.horizon_ns, math.inf, "pose")
        self.pose = Pose(message.x, message.y, message.theta)
        self.pose_stamp_ns = message.tm.to_nanoseconds()
        if self.navigation is not None:
            self.navigation.pose(self.pose_stamp_ns, self.pose)
        self._complete_tick()

    @property
    def pose_age_s(self) -> float | None:
        """Simulated seconds from the latest pose's stamp to the latest clock stamp."""
        if self.pose_stamp_ns is None or self.clock.last_ns is None:
            return None
        return (self.clock.last_ns - self.pose_stamp_ns) / NANOSECONDS_PER_SECOND

    def _fresh_pose(self, now_ns: int) -> Pose | None:
        """The latest pose, unless its stamp is further than ``pose_timeout`` from ``now_ns``:
        older (odometry stopped) or later (from before a simulator restart). Then None."""
        if self.pose_stamp_ns is None or abs(now_ns - self.pose_stamp_ns) > self.pose_timeout_ns:
            return None
        return self.pose

    def _restart(self, now_ns: int) -> None:
        """A new simulator, whose clock started again: the scenario starts over at ``now_ns``."""
        runner = self.runner
        if runner is not None:
            self.runner = ScenarioRunner(runner.scenario, runner.params, loop=runner.loop)
        self.schedule = None
        self.pose, self.pose_stamp_ns = None, None
        self._pending_tick = None
        self.final_zeros = 0
        self.outcome = None
        self.give_up.restart(now_ns)
        if self.goal_drive is not None:
            self.goal_drive.restart(now_ns)
        if self.navigation is not None:
            self.navigation.restart()
        self.node.log.info(
            "simulation time went back to %.3f s (a new simulator): %r starts over",
            now_ns / NANOSECONDS_PER_SECOND,
            "goal mode" if runner is None else runner.scenario.name,
        )

    def _on_clock(self, message: TimedDoubleSeq, attachment: bytes | None) -> None:
        now_ns = message.tm.to_nanoseconds()
        lockstep = decode_owed(attachment, now_ns) is not None
        if self.clock.advance(now_ns):
            self._restart(now_ns)
        # The simulator stepped on: it gave up waiting for a pending tick's command.
        self._complete_tick(stepped_on=True)
        if self.schedule is None:
            # Commands sent before the motor listens would be lost: the scenario starts once it does.
            if not self.publisher.matched:
                return
            self.schedule = PeriodicSchedule(self.rate_hz, 0)
            if self.runner is not None:
                start = self._fresh_pose(now_ns) or Pose(0.0, 0.0, 0.0)
                scenario = self.runner.scenario
                self._path.put(PlannedPath(message.tm, scenario.name, planned_path(scenario, start)))
        if self.finished or not self.schedule.due(now_ns):
            return
        if lockstep and self.odometry_alive:
            self._pending_tick = (now_ns, time.monotonic() + self.pose_wait_s)
            self._complete_tick()
        else:
            self._command(now_ns)

    def _complete_tick(self, stepped_on: bool = False) -> None:
        """Command the pending lockstep tick once the pose of its stamp has come, odometry is gone,
        the wait is over (odometry not in step), or the simulator has ``stepped_on`` without this
        tick's command."""
        if self._pending_tick is None:
            return
        tick_ns, deadline = self._pending_tick
        if self.pose_stamp_ns is None or self.pose_stamp_ns < tick_ns:
            if self.odometry_alive and not stepped_on and time.monotonic() < deadline:
                return
            if self.odometry_alive and not stepped_on and self.odometry_in_step:
                self.node.log.warning(
                    "still waiting for odometry/pose for t = %.3f s: odometry is alive",
                    tick_ns / NANOSECONDS_PER_SECOND,
                )
                self._pending_tick = (tick_ns, time.monotonic() + self.pose_wait_s)
                return
            if self.odometry_alive and not stepped_on:
                self.pose_wait_timeouts += 1
                self.node.log.warning(
                    "no odometry/pose for t = %.3f s within %g s: commanding from the latest pose",
                    tick_ns / NANOSECONDS_PER_SECOND,
                    self.pose_wait_s,
                )
        else:
            self.odometry_in_step = self.odometry_alive
        self._pending_tick = None
        self._command(tick_ns)

    def _command(self, tick_ns: int) -> None:
        command, done = self._goal_command(tick_ns) if self.goal_drive is not None else self._scenario_command(tick_ns)
        last = done and self.final_zeros + 1 >= FINAL_ZERO_TICKS
        tm = Time.from_nanoseconds(tick_ns)
        self.publisher.put(
            TimedVelocity(tm=tm, id=[], vx=command.vx, vy=0.0, w=command.w, error=[]), FINAL if last else None
        )
        self.commands_published += 1
        if not done:
            return
        self.final_zeros += 1
        if self.goal_drive is not None:
            if last:
                self.finished = True
            return
        runner = self.runner
        assert runner is not None
        if self.outcome is None:
            self.outcome = GiveUp(Outcome.COMPLETED, "")
        if self.final_zeros == 1:
            self._pass_elapsed_s = runner.pass_elapsed_ns / NANOSECONDS_PER_SECOND
            self.node.log.info("scenario %s after %.3f s of simulation time", self.outcome.outcome, runner.elapsed_s)
        if last:
            outcome = self.outcome
            self._outcome.put(
                ScenarioOutcome(
                    tm=tm,
                    scenario=runner.scenario.name,
                    outcome=outcome.outcome.value,
                    reason=outcome.reason,
                    iteration=runner.iteration,
                    elapsed_s=self._pass_elapsed_s,
                )
            )
            self.finished = True

    def _scenario_command(self, tick_ns: int) -> tuple[Command, bool]:
        """The scenario's command at this tick, and whether it is done (completed or given up)."""
        runner = self.runner
        assert runner is not None
        command = runner.step(tick_ns, self._fresh_pose(tick_ns))
        if not runner.done and (given_up := self.give_up.check(tick_ns, runner.pass_elapsed_ns)) is not None:
            runner.give_up()
            command, self.outcome = STOPPED, given_up
            self.node.log.warning("%s: %s", given_up.outcome, given_up.reason)
        return command, runner.done

    def _goal_command(self, tick_ns: int) -> tuple[Command, bool]:
        """Goal mode's command at this tick, and whether a goal file's run is over."""
        goal_drive = self.goal_drive
        assert goal_drive is not None
        navigation = self.navigation
        updated = navigation is not None and navigation.tick(tick_ns)
        command = goal_drive.tick(tick_ns, self._fresh_pose(tick_ns), updated)
        if navigation is not None:
            navigation.show_plan(tick_ns, goal_drive.goals.plan)
        if goal_drive.finished and self.final_zeros == 0:
            self.outcome = goal_drive.outcome
            self.node.log.info(
                "the goal file's goals are done after %.3f s of simulation time; the last %s",
                tick_ns / NANOSECONDS_PER_SECOND,
                "none" if self.outcome is None else self.outcome.outcome,
            )
        return command, goal_drive.finished

    def status(self) -> DriveStatus:
        runner = self.runner
        if runner is None:
            assert self.goal_drive is not None
            return msgspec.structs.replace(
                self._common_status(self.goal_drive.goals.command),
                goals=self.goal_drive.status(),
                navigation=None if self.navigation is None else self.navigation.status(),
            )
        return msgspec.structs.replace(
            self._common_status(runner.command),
            scenario=runner.scenario.name,
            loop=runner.loop,
            iteration=runner.iteration,
            segment_index=runner.segment_index,
            segments=len(runner.scenario.segments),
            elapsed_s=runner.elapsed_s,
            waypoint_index=runner.waypoint_index,
            follower_phase=runner.phase,
            done=runner.done,
        )

    def _common_status(self, command: Command) -> DriveStatus:
        give_up = self.give_up
        return DriveStatus(
            state=self.state,
            mode=self.mode,
            rate_hz=self.rate_hz,
            commands_published=self.commands_published,
            command=Velocity(command.vx, command.w),
            sim_alive=self.sim.alive,
            time_base_restarts=self.clock.restart.restarts,
            odometry_alive=self.odometry_alive,
            lockstep_participant=self.node.participating,
            pose_wait_timeouts=self.pose_wait_timeouts,
            time_limit_s=give_up.limit_s,
            motor_stopped_since_s=give_up.stopped_since_s,
            motor_held_since_s=give_up.held_since_s,
            motor_held_by=give_up.held_by,
            outcome=None if self.outcome is None else DriveOutcome(str(self.outcome.outcome), self.outcome.reason),
            pose=None if self.pose is None else PlanarPose(*self.pose),
            pose_age_s=self.pose_age_s,
        )

    def _next_wait(self) -> Wait:
        # Waiting in the input needed next, the drive sees a lockstep tick's clock and then its pose
        # as they arrive: a poll would add its period to every tick the whole loop waits for.
        self._complete_tick()
        if self._pending_tick is not None:
            return Wait(self._pose_input, until=self._pending_tick[1])
        return Wait(self._clock_input)

    def close(self) -> None:
        """Nothing beyond the node to release."""


COMMAND = ServiceCommand(service=Service.DRIVE, factory=DriveService, check=check)
