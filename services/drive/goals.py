"""Goals sent to a running drive (pure, no zenoh): docs/protocol.md section 7.3, docs/drive.md "Goals".

:class:`Goals` takes goals and cancels as they arrive (:meth:`Goals.send`, :meth:`Goals.cancel`:
each answered at once, accepted or rejected with the reason) and plays them at the drive's ticks
(:meth:`Goals.step`): an accepted goal starts at the next tick, preempting the one that runs; a
goal is reached with the scenarios' path follower (turn toward it if it lies far off the heading,
drive, stop) or its navigator, then a turn in place to its heading (services/drive/goal_approach.py); it ends ``completed`` at rest within its
tolerances, ``canceled`` once braked to a stop after a cancel (or at once when preempted), and
``aborted`` or ``timed_out`` when the drive gives it up (:meth:`Goals.give_up`, by the rule of
services/drive/outcome.py).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

from schemas.drive_status import EndedGoal, GoalsStatus, RunningGoalStatus
from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.navigation import MAX_GOAL_SECONDS, CancelReply, CancelRequest, GoalReply, GoalRequest
from services.config import DriveConfig, GoalsConfig, InputConfig, NavigationConfig
from services.drive.goal_approach import Goal, GoalApproach, Phase, RunningGoal
from services.drive.outcome import Outcome
from services.drive.path_following import STOPPED, Command
from services.drive.scenarios import goal_duration
from services.navigation.costmap import Costmap
from services.navigation.navigator import NavigatorPhase
from services.planar import Pose, wrap_angle

GOAL_FRAMES = ("map", "odom")
"""The frames a goal may be given in (docs/protocol.md section 7.3)."""
MAX_ATTEMPTS = 3
"""Approaches of one goal: a robot at rest outside the tolerances drives again, up to this many times."""
MAX_WAITING = 16
"""Goals accepted and replaced before the next tick (each to end ``canceled`` at that tick) that may
wait at once; more are rejected (a flood of goals, or a drive whose clock has stopped)."""
REMEMBERED_RESULTS = 16
"""Ended goals whose outcome a cancel of their id is told (the oldest forgotten first)."""


@dataclass(frozen=True)
class Started:
    """A goal started at this tick."""

    goal: Goal
    time_limit_s: float | None


@dataclass(frozen=True)
class Ended:
    """A goal ended at this tick."""

    goal: Goal
    outcome: Outcome
    reason: str
    elapsed_s: float


@dataclass(frozen=True)
class Progress:
    """The running goal's progress at a tick (``drive/goal/feedback``)."""

    goal: Goal
    canceling: bool
    distance_remaining: float
    """Along the plan while the goal navigates, else straight to it."""
    elapsed_s: float
    estimated_remaining_s: float
    recoveries: int = 0
    """Recoveries the goal's navigation has tried so far."""


@dataclass
class Tick:
    """What one tick of :meth:`Goals.step` did: the command, and the goals that ended and started."""

    command: Command
    ended: list[Ended] = field(default_factory=list)
    started: Started | None = None


def odom_to_map(origin: Pose, x: float, y: float, theta: float | None) -> tuple[float, float, float | None]:
    """A pose of the ``odom`` frame (the robot started at its origin, facing +x) in ``map``, where
    ``origin`` is the robot's initial pose."""
    cos, sin = math.cos(origin.theta), math.sin(origin.theta)
    return (
        origin.x + cos * x - sin * y,
        origin.y + sin * x + cos * y,
        None if theta is None else wrap_angle(origin.theta + theta),
    )


class Goals:
    """The drive's goals: call :meth:`send` and :meth:`cancel` as requests come, :meth:`step` at every tick."""

    def __init__(
        self,
        drive: DriveConfig,
        goals: GoalsConfig,
        bounds: InputConfig,
        odom_origin: Pose,
        costmap: Costmap | None = None,
        navigation: NavigationConfig | None = None,
    ) -> None:
        """``costmap`` (with ``navigation``, its settings): goals navigate on it (services/navigation/);
        None: each goal is driven along the straight line to it."""
        if (costmap is None) != (navigation is None):
            raise ValueError("a costmap goes with its navigation settings")
        self.costmap = costmap
        self.approach = GoalApproach(drive, costmap, navigation)
        self.drive = drive
        self.defaults = goals
        self.bounds = bounds
        self.odom_origin = odom_origin
        self.running: RunningGoal | None = None
        self.pending: Goal | None = None
        """Accepted, to start at the next tick."""
        self._pending_canceled = ""
        self._preempted: list[tuple[Goal, str]] = []
        """Accepted goals replaced before they started, each with why: they end at the next tick."""
        self.results: OrderedDict[str, Ended] = OrderedDict()
        self.last: Ended | None = None
        self.command = STOPPED
        self.counts = dict.fromkeys(
            ("accepted", "rejected", "completed", "canceled", "aborted", "timed_out", "cancel_rejected"), 0
        )
        self._made_ids = 0

    @property
    def idle(self) -> bool:
        """No goal runs, none is about to start, and none has an outcome still to give."""
        return self.running is None and self.pending is None and not self._preempted

    # --- requests, answered at once -------------------------------------------------------------

    def send(self, request: GoalRequest, pose: Pose | None, motor_stopped_by: str | None) -> GoalReply:
        """Accept ``request`` (to start at the next tick) or reject it, saying why. ``pose``: the
        robot's latest (None: none yet); ``motor_stopped_by``: who latched the motor's stop, None
        while it is not latched."""
        reason = self._refusal(request, pose, motor_stopped_by)
        if reason:
            self.counts["rejected"] += 1
            return GoalReply(False, "", reason)
        goal = self._accepted(request)
        if self.pending is not None:
            self._preempted.append((self.pending, f"preempted by goal {goal.id!r} before it started"))
        self.pending = goal
        self._pending_canceled = ""
        self.counts["accepted"] += 1
        return GoalReply(True, goal.id)

    def _refusal(self, request: GoalRequest, pose: Pose | None, motor_stopped_by: str | None) -> str:
        numbers = {
            "x": request.x,
            "y": request.y,
            "theta": request.theta,
            "position_tolerance": request.position_tolerance,
            "heading_tolerance": request.heading_tolerance,
            "time_limit": request.time_limit,
        }
        for name, value in numbers.items():
            if value is not None and not math.isfinite(value):
                return f"`{name}` must be finite, got {value}"
        for name in ("position_tolerance", "heading_tolerance", "time_limit"):
            value = numbers[name]
            if value is not None and value <= 0.0:
                return f"`{name}` must be > 0, got {value}"
        if request.time_limit is not None and request.time_limit > MAX_GOAL_SECONDS:
            return f"`time_limit` must be at most {MAX_GOAL_SECONDS:g} s, got {request.time_limit}"
        if request.frame not in GOAL_FRAMES:
            return f"unknown frame {request.frame!r}: a goal is in {' or '.join(GOAL_FRAMES)}"
        x, y, _ = self._in_map(request)
        limit = self.bounds.max_coordinate
        if abs(x) > limit or abs(y) > limit:
            return f"the goal ({x:.6g}, {y:.6g}) in map is beyond input.max_coordinate = {limit:g} m"
        if self.costmap is not None and not self.costmap.geometry.contains(x, y):
            geometry = self.costmap.geometry
            return (
                f"the goal ({x:.6g}, {y:.6g}) in map is off the costmap (x {geometry.origin_x:.2f} to "
                f"{geometry.max_x:.2f}, y {geometry.origin_y:.2f} to {geometry.max_y:.2f}): "
                "a goal navigates on the map, or on navigation.size around the start"
            )
        if len(self._preempted) >= MAX_WAITING:
            return f"{MAX_WAITING} goals already wait for the drive's next tick (is the simulation clock running?)"
        if request.id and (request.id in self._live_ids()):
            return f"goal {request.id!r} is still running: give a new goal a new id"
        if motor_stopped_by is not None:
            who = f" (by {motor_stopped_by})" if motor_stopped_by else ""
            return f"the motor is latched stopped{who}: clear it first (invent call clear)"
        if pose is None:
            return "no pose of the robot yet (odometry/pose): nothing to drive from"
        distance = math.hypot(x - pose.x, y - pose.y)
        if distance > self.defaults.max_distance:
            return f"the goal is {distance:.6g} m away, beyond goals.max_distance = {self.defaults.max_distance:g} m"
        return ""

    def _live_ids(self) -> set[str]:
        ids = {goal.id for goal, _ in self._preempted}
        if self.pending is not None:
            ids.add(self.pending.id)
        if self.running is not None:
            ids.add(self.running.goal.id)
        return ids

    def _in_map(self, request: GoalRequest) -> tuple[float, float, float | None]:
        if request.frame == "odom":
            return odom_to_map(self.odom_origin, request.x, request.y, request.theta)
        return request.x, request.y, None if request.theta is None else wrap_angle(request.theta)

    def _accepted(self, request: GoalRequest) -> Goal:
        goal_id = request.id
        if not goal_id:
            live = self._live_ids()
            while True:
                self._made_ids += 1
                goal_id = f"g{self._made_ids}"
                if goal_id not in live:
                    break
        x, y, theta = self._in_map(request)
        defaults = self.defaults
        return Goal(
            id=goal_id,
            x=x,
            y=y,
            theta=theta,
            frame=request.frame,
            position_tolerance=request.position_tolerance or defaults.position_tolerance,
            heading_tolerance=request.heading_tolerance or defaults.heading_tolerance,
            time_limit=request.time_limit,
        )

    def cancel(self, request: CancelRequest) -> CancelReply:
        """Cancel the goal ``request.id`` (``""``: whatever runs, or is about to): it brakes to a
        stop from the next tick and then ends ``canceled``. The reply names it, or says why none."""
        running, pending = self.running, self.pending
        wanted = request.id
        if pending is not None and wanted in ("", pending.id):
            self._pending_canceled = "canceled before it started"
            if running is not None and running.phase is not Phase.CANCELING and not wanted:
                self._begin_canceling(running)
                return CancelReply([running.goal.id, pending.id])
            return CancelReply([pending.id])
        if running is not None and wanted in ("", running.goal.id):
            if running.phase is not Phase.CANCELING:
                self._begin_canceling(running)
            return CancelReply([running.goal.id])
        self.counts["cancel_rejected"] += 1
        if not wanted:
            return CancelReply([], "no goal runs")
        if wanted in self.results:
            ended = self.results[wanted]
            return CancelReply([], f"goal {wanted!r} already ended: {ended.outcome}")
        return CancelReply([], f"unknown goal id {wanted!r}")

    def _begin_canceling(self, running: RunningGoal) -> None:
        running.phase = Phase.CANCELING
        running.cancel_reason = "canceled"

    # --- the ticks ------------------------------------------------------------------------------

    def step(self, now_ns: int, pose: Pose | None, dt: float, held_by: str = "") -> Tick:
        """The command from ``now_ns`` until the next tick (``dt`` s after the previous one), given
        the robot's ``pose`` (None: none fresh) and why the collision monitor holds it (``held_by``,
        "" while it does not); the goals that ended and started at this tick."""
        tick = Tick(STOPPED)
        for goal, reason in self._preempted:
            self._end(tick, goal, Outcome.CANCELED, reason, 0.0)
        self._preempted.clear()
        if self.pending is not None:
            goal, self.pending = self.pending, None
            if self._pending_canceled:
                self._end(tick, goal, Outcome.CANCELED, self._pending_canceled, 0.0)
            else:
                if self.running is not None:
                    self._end_running(tick, now_ns, Outcome.CANCELED, f"preempted by goal {goal.id!r}")
                tick.started = self._start(goal, now_ns, pose)
        running = self.running
        if running is None:
            self.command = STOPPED
            return tick
        command = self.approach.step(running, self.command, now_ns, pose, dt, held_by)
        navigator = running.navigator
        if navigator is not None and navigator.phase is NavigatorPhase.FAILED:
            self.command = command
            self._end_running(tick, now_ns, Outcome.ABORTED, navigator.failure)
            tick.command = command
            return tick
        if running.phase is Phase.CANCELING and command == STOPPED:
            self._end_running(tick, now_ns, Outcome.CANCELED, running.cancel_reason)
        elif running.phase is Phase.SETTLE and pose is not None and self.approach.settled(running, now_ns):
            self._judge(tick, running, now_ns, pose)
        self.command = command
        tick.command = command
        return tick

    def _start(self, goal: Goal, now_ns: int, pose: Pose | None) -> Started:
        limit = goal.time_limit
        if limit is None and self.drive.time_limit_factor is not None and pose is not None:
            planned = goal_duration(pose, goal.x, goal.y, goal.theta, self.drive)
            limit = self.drive.time_limit_factor * planned + self.drive.time_limit_margin
        self.running = RunningGoal(goal, now_ns, limit)
        return Started(goal, limit)

    def _judge(self, tick: Tick, running: RunningGoal, now_ns: int, pose: Pose) -> None:
        """At rest: ``completed`` within the tolerances, else drive again (or give up after
        :data:`MAX_ATTEMPTS`)."""
        goal = running.goal
        distance = math.hypot(goal.x - pose.x, goal.y - pose.y)
        heading_error = 0.0 if goal.theta is None else abs(wrap_angle(goal.theta - pose.theta))
        if distance <= goal.position_tolerance and heading_error <= goal.heading_tolerance:
            self._end_running(tick, now_ns, Outcome.COMPLETED, "")
            return
        if running.attempts >= MAX_ATTEMPTS:
            self._end_running(
                tick,
                now_ns,
                Outcome.ABORTED,
                f"at rest {distance:.3f} m and {heading_error:.3f} rad from the goal after {running.attempts} "
                f"approaches (tolerances {goal.position_tolerance:g} m, {goal.heading_tolerance:g} rad)",
            )
            return
        running.attempts += 1
        running.settle_since_ns, running.settle_pose = None, None
        running.navigator = None
        running.phase = Phase.APPROACH if distance > goal.position_tolerance else Phase.ALIGN

    def give_up(self, now_ns: int, outcome: Outcome, reason: str) -> Ended | None:
        """End the running goal as the drive gives it up (``aborted``, ``timed_out``); the command is zero at once."""
        if self.running is None:
            return None
        tick = Tick(STOPPED)
        self._end_running(tick, now_ns, outcome, reason)
        self.command = STOPPED
        return tick.ended[0]

    def _end_running(self, tick: Tick, now_ns: int, outcome: Outcome, reason: str) -> None:
        assert self.running is not None
        running, self.running = self.running, None
        self._end(tick, running.goal, outcome, reason, (now_ns - running.start_ns) / NANOSECONDS_PER_SECOND)

    def _end(self, tick: Tick, goal: Goal, outcome: Outcome, reason: str, elapsed_s: float) -> None:
        ended = Ended(goal, outcome, reason, elapsed_s)
        tick.ended.append(ended)
        self.counts[str(outcome)] += 1
        self.results[goal.id] = ended
        self.results.move_to_end(goal.id)
        while len(self.results) > REMEMBERED_RESULTS:
            self.results.popitem(last=False)
        self.last = ended

    # --- progress -------------------------------------------------------------------------------

    def progress(self, now_ns: int, pose: Pose) -> Progress | None:
        """The running goal's progress at ``now_ns`` from ``pose``; None when no goal runs."""
        running = self.running
        if running is None:
            return None
        goal = running.goal
        canceling = running.phase is Phase.CANCELING
        distance, estimate = self.approach.remaining(running, pose)
        navigator = running.navigator
        return Progress(
            goal=goal,
            canceling=canceling,
            distance_remaining=distance,
            elapsed_s=(now_ns - running.start_ns) / NANOSECONDS_PER_SECOND,
            estimated_remaining_s=0.0 if canceling else estimate,
            recoveries=0 if navigator is None else navigator.recoveries,
        )

    @property
    def plan(self) -> tuple[str, int, tuple[tuple[float, float], ...]] | None:
        """The running goal's plan as (goal id, version, points), the version increasing with every
        new plan; None when no goal navigates or it has no plan yet."""
        running = self.running
        navigator = None if running is None else running.navigator
        if running is None or navigator is None or navigator.plan is None:
            return None
        return running.goal.id, navigator.plan_version, navigator.plan.points

    def status(self, feedback_published: int, file_entries_sent: int | None, file_entries: int | None) -> GoalsStatus:
        """The goals' part of ``drive/status``, with what the shell published and sent from a goal file."""
        running = self.running
        last = self.last
        return GoalsStatus(
            running=None
            if running is None
            else RunningGoalStatus(
                id=running.goal.id,
                phase=str(running.phase),
                x=running.goal.x,
                y=running.goal.y,
                theta=running.goal.theta,
                attempt=running.attempts,
                time_limit_s=running.time_limit_s,
                navigation=None if running.navigator is None else running.navigator.status(),
            ),
            pending=None if self.pending is None else self.pending.id,
            last=None if last is None else EndedGoal(last.goal.id, str(last.outcome), last.reason, last.elapsed_s),
            **self.counts,
            feedback_published=feedback_published,
            file_entries_sent=file_entries_sent,
            file_entries=file_entries,
        )
