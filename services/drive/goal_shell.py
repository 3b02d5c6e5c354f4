"""The drive's goal mode on zenoh (``invent drive --goals``, ``--goal-file``): docs/protocol.md section 7.3.

The shell of :class:`~services.drive.goals.Goals`: it answers ``drive/goal/send`` and
``drive/goal/cancel`` (on the service thread, at once), sends a goal file's entries through the same
two calls at their ticks, and at each of the drive's ticks gives the command, publishes the goal
that started (``drive/goal``, latched), the feedback (``drive/goal/feedback`` at
``goals.feedback_rate``) and each goal's result (``drive/outcome``, latched), and gives a goal up by
the drive's rule (services/drive/outcome.py).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from schemas.codec import BadMessage, decode
from schemas.drive_status import GoalsStatus
from schemas.messages import NANOSECONDS_PER_SECOND, ScenarioOutcome, Time
from schemas.navigation import CancelReply, CancelRequest, GoalFeedback, GoalReply, GoalRequest, GoalTarget
from services.clock.sim_time import PeriodicSchedule
from services.config import Config
from services.drive.goal_file import GoalFile, GoalSchedule
from services.drive.goals import Ended, Goals, Started
from services.drive.outcome import GiveUp, GiveUpRule, Outcome
from services.drive.path_following import Command
from services.navigation.costmap import Costmap
from services.planar import Pose
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node

GOALS_SCENARIO = "goals"
"""``drive/outcome``'s ``scenario`` for a goal's result."""


class GoalDrive:
    """Goal mode: call :meth:`tick` at every drive tick; it answers the goal queryables itself."""

    def __init__(
        self,
        node: Node,
        config: Config,
        goal_file: GoalFile | None,
        give_up: GiveUpRule,
        latest_pose: Callable[[], Pose | None],
        motor_stopped_by: Callable[[], str | None],
        costmap: Costmap | None = None,
    ) -> None:
        """``costmap``: goals navigate on it (``navigation.enabled``); None: the straight line."""
        self.node = node
        self._refusals = RateLimitedLog(node.log)
        """A rejected goal or cancel is said once a second at most: anyone may send them at will."""
        odometry = config.odometry
        self.goals = Goals(
            config.drive,
            config.goals,
            config.input,
            Pose(odometry.initial_x, odometry.initial_y, odometry.initial_theta),
            costmap,
            None if costmap is None else config.navigation,
        )
        self.give_up = give_up
        self._latest_pose = latest_pose
        self._motor_stopped_by = motor_stopped_by
        self.schedule = GoalSchedule(goal_file) if goal_file is not None else None
        self._feedback_rate = config.goals.feedback_rate
        self._feedback_schedule: PeriodicSchedule | None = None
        self._start_ns: int | None = None
        self._last_tick_ns: int | None = None
        self.feedback_published = 0
        self._goal = node.latched_publisher(node.keys.drive_goal)
        self._feedback = node.publisher(node.keys.drive_goal_feedback)
        self._outcome = node.latched_publisher(node.keys.drive_outcome)
        node.queryable(node.keys.drive_goal_send, self._on_send, mutates=True)
        node.queryable(node.keys.drive_goal_cancel, self._on_cancel, mutates=True)

    @property
    def finished(self) -> bool:
        """A goal file's run is over: every entry sent, and no goal runs or waits to start."""
        return self.schedule is not None and self.schedule.exhausted and self.goals.idle

    @property
    def outcome(self) -> GiveUp | None:
        """The last goal's result, as the drive's exit code reads it."""
        last = self.goals.last
        return None if last is None else GiveUp(last.outcome, last.reason)

    def _on_send(self, payload: bytes) -> GoalReply:
        try:
            request = decode(GoalRequest, payload)
        except BadMessage as error:
            self.node.bad_inputs.record(self.node.keys.drive_goal_send, str(error))
            self.goals.counts["rejected"] += 1
            return GoalReply(False, "", f"not a GoalRequest: {error}")
        return self._send(request, self._latest_pose())

    def _send(self, request: GoalRequest, pose: Pose | None) -> GoalReply:
        reply = self.goals.send(request, pose, self._motor_stopped_by())
        if reply.accepted:
            self.node.log.info("goal %r accepted: (%g, %g) in %s", reply.id, request.x, request.y, request.frame)
        else:
            self._refusals("goal_rejected", logging.WARNING, "goal rejected: %s", reply.reason)
        return reply

    def _on_cancel(self, payload: bytes) -> CancelReply:
        try:
            request = decode(CancelRequest, payload) if payload.strip() else CancelRequest()
        except BadMessage as error:
            self.node.bad_inputs.record(self.node.keys.drive_goal_cancel, str(error))
            self.goals.counts["cancel_rejected"] += 1
            return CancelReply([], f"not a CancelRequest: {error}")
        return self._cancel(request)

    def _cancel(self, request: CancelRequest) -> CancelReply:
        reply = self.goals.cancel(request)
        if reply.canceling:
            self.node.log.info("canceling %s", ", ".join(map(repr, reply.canceling)))
        else:
            self._refusals("cancel_refused", logging.WARNING, "cancel refused: %s", reply.reason)
        return reply

    def tick(self, tick_ns: int, pose: Pose | None, costmap_updated: bool = False) -> Command:
        """The command from ``tick_ns`` until the next tick, with ``pose`` the robot's (None: none
        fresh); ``costmap_updated``: the costmap took scans since the last tick."""
        if self._start_ns is None:
            self._start_ns = tick_ns
            self._feedback_schedule = PeriodicSchedule(self._feedback_rate, 0)
        if self.schedule is not None and pose is not None:  # a file's goal is sent from a pose of its tick
            for entry in self.schedule.due(tick_ns - self._start_ns):
                request = entry.request()
                if isinstance(request, CancelRequest):
                    self._cancel(request)
                else:
                    self._send(request, pose)
        dt = 0.0 if self._last_tick_ns is None else (tick_ns - self._last_tick_ns) / NANOSECONDS_PER_SECOND
        self._last_tick_ns = tick_ns
        running = self.goals.running
        if costmap_updated and running is not None and running.navigator is not None:
            running.navigator.costmap_updated()
        step = self.goals.step(tick_ns, pose, dt, self.give_up.held_by)
        for ended in step.ended:
            self._ended(tick_ns, ended)
        if step.started is not None:
            self._started(tick_ns, step.started)
        command = step.command
        running = self.goals.running
        if running is not None:
            # A navigated goal recovers from the collision monitor's holds itself (its navigator).
            given_up = self.give_up.check(
                tick_ns, tick_ns - running.start_ns, from_ns=running.start_ns, holds=self.goals.costmap is None
            )
            if given_up is not None and (gone := self.goals.give_up(tick_ns, given_up.outcome, given_up.reason)):
                self._ended(tick_ns, gone)
                command = self.goals.command
        assert self._feedback_schedule is not None
        if self._feedback_schedule.due(tick_ns) and pose is not None:
            self._publish_feedback(tick_ns, pose)
        return command

    def _started(self, tick_ns: int, started: Started) -> None:
        goal = started.goal
        self.give_up.limit(started.time_limit_s)
        self._goal.put(
            GoalTarget(
                tm=Time.from_nanoseconds(tick_ns),
                id=goal.id,
                x=goal.x,
                y=goal.y,
                theta=goal.theta,
                frame=goal.frame,
                position_tolerance=goal.position_tolerance,
                heading_tolerance=goal.heading_tolerance,
                time_limit_s=started.time_limit_s,
            )
        )
        self.node.log.info(
            "goal %r started at t = %.3f s: (%.3f, %.3f)%s in map",
            goal.id,
            tick_ns / NANOSECONDS_PER_SECOND,
            goal.x,
            goal.y,
            "" if goal.theta is None else f", heading {goal.theta:.3f} rad",
        )

    def _ended(self, tick_ns: int, ended: Ended) -> None:
        self._outcome.put(
            ScenarioOutcome(
                tm=Time.from_nanoseconds(tick_ns),
                scenario=GOALS_SCENARIO,
                outcome=ended.outcome.value,
                reason=ended.reason,
                iteration=0,
                elapsed_s=ended.elapsed_s,
                goal_id=ended.goal.id,
            )
        )
        log = self.node.log.info if ended.outcome is Outcome.COMPLETED else self.node.log.warning
        log(
            "goal %r %s after %.3f s%s",
            ended.goal.id,
            ended.outcome,
            ended.elapsed_s,
            f": {ended.reason}" if ended.reason else "",
        )

    def _publish_feedback(self, tick_ns: int, pose: Pose) -> None:
        progress = self.goals.progress(tick_ns, pose)
        if progress is None:
            return
        self._feedback.put(
            GoalFeedback(
                tm=Time.from_nanoseconds(tick_ns),
                id=progress.goal.id,
                state="canceling" if progress.canceling else "executing",
                x=pose.x,
                y=pose.y,
                theta=pose.theta,
                distance_remaining=progress.distance_remaining,
                elapsed_s=progress.elapsed_s,
                estimated_remaining_s=progress.estimated_remaining_s,
                recoveries=progress.recoveries,
            )
        )
        self.feedback_published += 1

    def restart(self, now_ns: int) -> None:
        """A new simulator (the robot back at its start): the running goal is aborted, a goal file starts over."""
        if (ended := self.goals.give_up(now_ns, Outcome.ABORTED, "the simulator restarted")) is not None:
            self._ended(now_ns, ended)
        if self.schedule is not None:
            self.schedule.sent = 0
        self._start_ns = self._last_tick_ns = None

    def status(self) -> GoalsStatus:
        return self.goals.status(
            feedback_published=self.feedback_published,
            file_entries_sent=None if self.schedule is None else self.schedule.sent,
            file_entries=None if self.schedule is None else len(self.schedule.entries),
        )
