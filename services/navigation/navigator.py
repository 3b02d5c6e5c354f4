"""The navigator: one goal's way there, with its recoveries (pure, no zenoh; docs/navigation.md).

Nav2's navigator in small: plan on the costmap (services/navigation/planner.py), follow the plan with
the path tracker (services/navigation/tracker.py), replan at ``replan_rate`` and at once when what the
lidar sees blocks the rest of the plan (:meth:`Navigator.costmap_updated`), and, when blocked, recover:

- **blocked** is: no plan to the goal; the collision monitor holding the robot (``motor/state``'s
  ``held_by``) for ``blocked_timeout``; or the robot moving less than ``progress_distance`` in
  ``progress_timeout`` (Nav2's progress checker);
- the **recoveries** come in turn (Nav2's default behaviour tree's): clear the costmap's obstacle layer
  (what the lidar saw, and may have seen wrong), wait ``wait_duration`` (for what moves to go), back up
  ``backup_distance`` (only where the costmap is clear behind), spin ``spin_angle`` (toward the goal's
  side); each ends with the robot at rest and a new plan. After ``max_recoveries`` the goal fails,
  naming why: ``no path to (4.00, 0.00): ...``, ``blocked by 'box' for 12.0 s: ...``.

A goal in an obstacle of the map, or too close to one for the body, fails at once (clearing what the
lidar saw changes nothing there): never a drive to some other cell. Arrival is the tracker's end of
the plan; whether the robot is within the goal's tolerances is judged by the caller at rest
(services/drive/goals.py), as for a goal driven along the straight line.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from schemas.drive_status import NavigatorStatus
from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import DriveConfig, NavigationConfig
from services.drive.path_following import STOPPED, Command, limit_rate
from services.navigation.costmap import INSCRIBED, LETHAL, Costmap
from services.navigation.planner import NoPlan, Plan, plan_path
from services.navigation.tracker import PathTracker
from services.planar import Pose, wrap_angle

CLEAR_SETTLE_S = 0.25
"""After the obstacle layer is cleared, the robot stands still this long (two scans at 10 Hz) so that
the lidar marks again what is really there before the next plan."""
REPLAN_GAIN = 0.9
"""A periodic replan replaces a plan that is not blocked only when its length is below this share of
what is left of the old one (less a cell): two ways of about the same length around an obstacle would
otherwise take turns, the robot weaving between them."""
PERMANENT = ("is in an obstacle", "the robot cannot stand there", "is off the costmap")
"""What a planner's reason says when no recovery can help: the goal's cell itself (of the map, since
the obstacle layer was just cleared) or the costmap's extent."""
_NAMED_OBSTACLE = re.compile(r"obstacle ('[^']*')")


class NavigatorPhase(StrEnum):
    PLAN = "plan"
    FOLLOW = "follow"
    RECOVER = "recover"
    ARRIVED = "arrived"
    FAILED = "failed"


class Recovery(StrEnum):
    CLEAR = "clear"
    WAIT = "wait"
    BACK_UP = "back_up"
    SPIN = "spin"


RECOVERY_ORDER = (Recovery.CLEAR, Recovery.WAIT, Recovery.BACK_UP, Recovery.SPIN)


@dataclass
class _Recovering:
    kind: Recovery
    start_ns: int
    start: Pose
    limit_ns: int
    direction: float = 1.0
    turned: float = 0.0
    last_theta: float = 0.0
    braking: bool = False


def _ns(seconds: float) -> int:
    return round(seconds * NANOSECONDS_PER_SECOND)


class Navigator:
    """One goal's navigation: call :meth:`step` at every tick of the drive, :meth:`costmap_updated`
    after the costmap took scans."""

    def __init__(
        self,
        goal: tuple[float, float],
        costmap: Costmap,
        drive: DriveConfig,
        settings: NavigationConfig,
        command: Command = STOPPED,
    ) -> None:
        self.goal = goal
        self.costmap = costmap
        self.drive = drive
        self.settings = settings
        self.command = command
        self.phase = NavigatorPhase.PLAN
        self.plan: Plan | None = None
        self.plan_version = 0
        """Increases with every new plan (the drive publishes ``drive/plan`` when it changes)."""
        self.tracker: PathTracker | None = None
        self.replans = 0
        self.recoveries = 0
        self.failure = ""
        """Why the goal failed, once :attr:`phase` is ``failed``."""
        self._recovering: _Recovering | None = None
        self._why = ""
        """The latest cause of a recovery: what the failure will name."""
        self._blocked_since_ns: int | None = None
        self._episode_distance = math.inf
        self._next_plan_ns = 0
        self._plan_blocked = False
        self._held_since_ns: int | None = None
        self._checkpoint: tuple[int, Pose] | None = None
        self._replan_period_ns = _ns(1.0 / settings.replan_rate)

    @property
    def finished(self) -> bool:
        return self.phase in (NavigatorPhase.ARRIVED, NavigatorPhase.FAILED)

    @property
    def recovery(self) -> str | None:
        return None if self._recovering is None else str(self._recovering.kind)

    def costmap_updated(self) -> None:
        """The costmap changed: if what is left of the plan now crosses a cell where the body would
        touch, replan at the next tick."""
        if self.phase is NavigatorPhase.FOLLOW and self.tracker is not None and self._remaining_blocked():
            self._plan_blocked = True

    def step(self, now_ns: int, pose: Pose, dt: float, held_by: str = "") -> Command:
        """The command for the next ``dt`` seconds from ``pose``; ``held_by``: why the collision
        monitor holds the robot ("" while it does not)."""
        if self.finished:
            return self._brake(dt)
        if not held_by:
            self._held_since_ns = None
        elif self._held_since_ns is None:
            self._held_since_ns = now_ns
        if self.phase is NavigatorPhase.PLAN:
            self._replan(now_ns, pose, forced=True)
        if self.phase is NavigatorPhase.FOLLOW:
            self._check_blocked(now_ns, pose, held_by)
        if self.phase is NavigatorPhase.FOLLOW and (self._plan_blocked or now_ns >= self._next_plan_ns):
            self._replan(now_ns, pose, forced=self._plan_blocked)
        if self.phase is NavigatorPhase.FOLLOW:
            assert self.tracker is not None
            self.command = self.tracker.step(pose, dt, self.costmap.cost_at(pose.x, pose.y))
            if self.tracker.done:
                self.phase = NavigatorPhase.ARRIVED
            self._progress(now_ns, pose)
            return self.command
        if self.phase is NavigatorPhase.RECOVER:
            return self._recover(now_ns, pose, dt)
        return self._brake(dt)

    # --- plans ----------------------------------------------------------------------------------

    def _replan(self, now_ns: int, pose: Pose, forced: bool) -> None:
        self._next_plan_ns = now_ns + self._replan_period_ns
        self._plan_blocked = False
        result = plan_path(self.costmap, (pose.x, pose.y), self.goal, self.settings.cost_weight)
        self.replans += 1
        if isinstance(result, NoPlan):
            self._blocked(now_ns, pose, f"no path to ({self.goal[0]:.2f}, {self.goal[1]:.2f}): {result.reason}")
            return
        tracker = self.tracker
        if not forced and tracker is not None and self.phase is NavigatorPhase.FOLLOW:
            left = math.hypot(*self._projection_offset(pose)) + tracker.remaining
            if result.length >= REPLAN_GAIN * left - self.costmap.geometry.resolution:
                return
        self._adopt(result, now_ns, pose)

    def _adopt(self, plan: Plan, now_ns: int, pose: Pose) -> None:
        self.plan = plan
        self.plan_version += 1
        self.tracker = PathTracker(plan.points, self.drive, self.settings, self.command)
        self.phase = NavigatorPhase.FOLLOW
        if self._checkpoint is None:
            self._checkpoint = (now_ns, pose)

    def _projection_offset(self, pose: Pose) -> tuple[float, float]:
        """From the robot to the first point of what is left of the plan."""
        assert self.tracker is not None
        x, y = self.tracker.remaining_points()[0]
        return x - pose.x, y - pose.y

    def _remaining_blocked(self) -> bool:
        """Whether what is left of the plan, beyond the robot's own reach, crosses a cell where the body
        would touch (a plan that escapes from such a cell is not blocked by its own start)."""
        assert self.tracker is not None
        points = self.tracker.remaining_points()
        geometry = self.costmap.geometry
        step = geometry.resolution / 2.0
        xs: list[np.ndarray] = []
        ys: list[np.ndarray] = []
        for (ax, ay), (bx, by) in itertools.pairwise(points):
            count = max(1, math.ceil(math.hypot(bx - ax, by - ay) / step))
            fractions = np.arange(count + 1) / count
            xs.append(ax + (bx - ax) * fractions)
            ys.append(ay + (by - ay) * fractions)
        if not xs:
            return False
        x, y = np.concatenate(xs), np.concatenate(ys)
        origin = points[0]
        beyond = np.hypot(x - origin[0], y - origin[1]) > self.costmap.inscribed_radius + geometry.resolution
        cols, rows, on_grid = geometry.cells_of(x[beyond], y[beyond])
        costs = self.costmap.costs[rows, cols]
        return bool(np.any(~on_grid | (costs >= INSCRIBED)))

    # --- blocked, progress ----------------------------------------------------------------------

    def _check_blocked(self, now_ns: int, pose: Pose, held_by: str) -> None:
        settings = self.settings
        held = self._held_since_ns
        if held is not None and now_ns - held >= _ns(settings.blocked_timeout):
            self._blocked(now_ns, pose, self._held_reason(held_by))
            return
        checkpoint = self._checkpoint
        if checkpoint is not None and now_ns - checkpoint[0] >= _ns(settings.progress_timeout):
            self._blocked(
                now_ns,
                pose,
                f"no progress: moved less than {settings.progress_distance:g} m in {settings.progress_timeout:g} s",
            )

    def _held_reason(self, held_by: str) -> str:
        named = _NAMED_OBSTACLE.search(held_by)
        return f"blocked by {named.group(1) if named else 'an obstacle'} for {{blocked_s}}: {held_by}"

    def _progress(self, now_ns: int, pose: Pose) -> None:
        checkpoint = self._checkpoint
        if checkpoint is None or math.hypot(pose.x - checkpoint[1].x, pose.y - checkpoint[1].y) >= (
            self.settings.progress_distance
        ):
            self._checkpoint = (now_ns, pose)
        distance = math.hypot(self.goal[0] - pose.x, self.goal[1] - pose.y)
        if (
            self._blocked_since_ns is not None
            and distance <= self._episode_distance - 2.0 * self.settings.progress_distance
        ):
            self._blocked_since_ns = None  # the way opened: a later block is a new episode

    def _blocked(self, now_ns: int, pose: Pose, why: str) -> None:
        """The robot cannot go on: the next recovery, or the goal fails."""
        if self._blocked_since_ns is None:
            self._blocked_since_ns = now_ns
            self._episode_distance = math.hypot(self.goal[0] - pose.x, self.goal[1] - pose.y)
        blocked_s = (now_ns - self._blocked_since_ns) / NANOSECONDS_PER_SECOND
        self._why = why.replace("{blocked_s}", f"{blocked_s:.1f} s")
        permanent = self.recoveries > 0 and any(phrase in why for phrase in PERMANENT)
        if permanent or self.recoveries >= self.settings.max_recoveries:
            tried = self.recoveries
            self._fail(
                f"{self._why} ({tried} {'recovery' if tried == 1 else 'recoveries'} tried)" if tried else self._why
            )
            return
        kind = RECOVERY_ORDER[self.recoveries % len(RECOVERY_ORDER)]
        self.recoveries += 1
        self.phase = NavigatorPhase.RECOVER
        self.tracker = None
        self._held_since_ns = None
        self._checkpoint = None
        bearing = wrap_angle(math.atan2(self.goal[1] - pose.y, self.goal[0] - pose.x) - pose.theta)
        self._recovering = _Recovering(
            kind,
            now_ns,
            pose,
            now_ns + _ns(self._recovery_limit_s(kind)),
            1.0 if bearing >= 0.0 else -1.0,
            last_theta=pose.theta,
        )
        if kind is Recovery.CLEAR:
            self.costmap.clear_obstacles()
        elif kind is Recovery.BACK_UP and not self._clear_behind(pose):
            self._recovering.limit_ns = now_ns  # nowhere to back up to: on to the plan (and the next recovery)

    def _recovery_limit_s(self, kind: Recovery) -> float:
        settings, drive = self.settings, self.drive
        if kind is Recovery.CLEAR:
            return CLEAR_SETTLE_S
        if kind is Recovery.WAIT:
            return settings.wait_duration
        if kind is Recovery.BACK_UP:
            return 2.0 * settings.backup_distance / settings.backup_speed + 1.0
        return 2.0 * settings.spin_angle / drive.max_turn_rate + 1.0

    def _fail(self, reason: str) -> None:
        self.phase = NavigatorPhase.FAILED
        self.failure = reason
        self.tracker = None
        self._recovering = None

    # --- recoveries -----------------------------------------------------------------------------

    def _recover(self, now_ns: int, pose: Pose, dt: float) -> Command:
        recovering = self._recovering
        assert recovering is not None
        if not recovering.braking:
            target = self._recovery_target(recovering, now_ns, pose)
            if target is None:
                recovering.braking = True
            else:
                return self._ramp(target, dt)
        command = self._brake(dt)
        if command == STOPPED:
            self._recovering = None
            self.phase = NavigatorPhase.PLAN
            self._replan(now_ns, pose, forced=True)
        return command

    def _recovery_target(self, recovering: _Recovering, now_ns: int, pose: Pose) -> Command | None:
        """The recovery's command now, or None once it is over (the robot then brakes to rest)."""
        if now_ns >= recovering.limit_ns:
            return None
        settings = self.settings
        if recovering.kind in (Recovery.CLEAR, Recovery.WAIT):
            return STOPPED
        if recovering.kind is Recovery.BACK_UP:
            moved = math.hypot(pose.x - recovering.start.x, pose.y - recovering.start.y)
            if moved >= settings.backup_distance:
                return None
            return Command(-settings.backup_speed, 0.0)
        recovering.turned += abs(wrap_angle(pose.theta - recovering.last_theta))
        recovering.last_theta = pose.theta
        left = settings.spin_angle - recovering.turned
        if left <= self.drive.heading_tolerance:
            return None
        drive = self.drive
        rate = min(drive.max_turn_rate, math.sqrt(drive.max_angular_acceleration * left))
        return Command(0.0, recovering.direction * rate)

    def _clear_behind(self, pose: Pose) -> bool:
        """Whether the costmap lets the robot back up: no cell on its way back (and a body's radius
        beyond) is lethal, and none gets closer to an obstacle than where it stands."""
        reach = self.settings.backup_distance + self.costmap.inscribed_radius
        steps = max(2, math.ceil(reach / (self.costmap.geometry.resolution / 2.0)))
        here = self.costmap.cost_at(pose.x, pose.y)
        for index in range(1, steps + 1):
            distance = reach * index / steps
            x = pose.x - math.cos(pose.theta) * distance
            y = pose.y - math.sin(pose.theta) * distance
            cost = self.costmap.cost_at(x, y)
            if cost >= LETHAL or (distance <= self.settings.backup_distance and cost >= INSCRIBED and cost > here):
                return False
        return True

    # --- commands -------------------------------------------------------------------------------

    def _ramp(self, target: Command, dt: float) -> Command:
        drive = self.drive
        self.command = limit_rate(self.command, target, dt, drive.max_acceleration, drive.max_angular_acceleration)
        return self.command

    def _brake(self, dt: float) -> Command:
        return self._ramp(STOPPED, dt)

    def status(self) -> NavigatorStatus:
        return NavigatorStatus(
            phase=str(self.phase),
            recovery=self.recovery,
            recoveries=self.recoveries,
            replans=self.replans,
            plan_length=None if self.plan is None else self.plan.length,
            remaining=None if self.tracker is None else self.tracker.remaining,
            failure=self.failure,
        )
