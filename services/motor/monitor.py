"""The collision monitor's state beside MotorCore (docs/protocol.md section 4.10): pure, no zenoh.

:class:`CollisionMonitor` takes the scans (:meth:`~CollisionMonitor.take_scan`, bad ones raise
BadInput and change nothing; each applies from the first control cycle stamped after it) and, at every control cycle, gives the factor the command is
multiplied by (:meth:`~CollisionMonitor.factor`): 0 while held (``min_points`` of the scan's points
in the stop zone, or no scan for ``scan_timeout``), ``slow_factor`` while as many are in the
slow-down zone, else 1.
The geometry (services/motor/collision.py, numpy) runs only when a scan arrives or the command
changes; a cycle otherwise compares two floats and a stamp. A hold is not latched: it ends with its
cause, and is not a state of the Motor state machine (the motor stays ``running``).
"""

from __future__ import annotations

from collections import deque

from schemas.messages import NANOSECONDS_PER_SECOND, LaserScan
from schemas.status import CollisionCounters, CollisionMonitorStatus, NearestObstacle
from services.clock.sim_time import StampGap, check_stamp_near
from services.config import RobotConfig
from services.config.sensors import CollisionMonitorConfig, LidarConfig
from services.motor.collision import CLEAR, MonitorGeometry, Obstacle, ScanPoints, Verdict, Zone, judge

PENDING_SCANS = 8
"""The most scans waiting for their first cycle (one does, at 10 Hz of 1 ms steps); beyond, the
oldest is dropped: a newer one supersedes it."""
OBSTACLE = "obstacle"
STALE_SCAN = "stale_scan"


class CollisionMonitor:
    """One robot's monitor: its geometry and settings locked at construction."""

    def __init__(
        self, robot: RobotConfig, lidar: LidarConfig, settings: CollisionMonitorConfig, horizon_ns: int
    ) -> None:
        self.settings = settings
        self.geometry = MonitorGeometry.of(robot, lidar, settings)
        self._slow_factor = settings.slow_factor
        self._timeout_ns = round(settings.scan_timeout * NANOSECONDS_PER_SECOND)
        self._horizon_ns = horizon_ns
        self._gap = StampGap(horizon_ns)

        self._pending: deque[tuple[int, ScanPoints]] = deque(maxlen=PENDING_SCANS)
        """Scans taken, not yet applied: (stamp, points)."""
        self._taken_ns: int | None = None
        """The stamp of the last scan taken: the next must be after it."""
        self._points: ScanPoints | None = None
        self.scan_ns: int | None = None
        """The stamp of the scan applied last; None before the first (of this time base)."""
        self.nearest: Obstacle | None = None
        """The point of the last scan nearest the body."""
        self._judged = False
        """Whether ``verdict`` is for the last scan and the command (``_vx``, ``_w``)."""
        self._vx = self._w = 0.0
        self.verdict: Verdict = CLEAR
        self._factor = 1.0

        self.held_by = ""
        """Why the robot is held (``motor/state``'s ``held_by``); "" while it is not."""
        self._cause: tuple[str, str] | None = None
        """The hold's cause: (OBSTACLE, body) or (STALE_SCAN, ""); held_by changes with it only."""
        self.held_since_ns: int | None = None
        self._slowed = False

        self.scans = 0
        self.scan_rays = 0
        self.holds = 0
        self.holds_by = {OBSTACLE: 0, STALE_SCAN: 0}
        self.slowdowns = 0

    def take_scan(self, scan: LaserScan, wheel_ns: int | None) -> None:
        """Take ``scan``, to apply from the first cycle stamped after it (:meth:`factor`); BadInput
        (nothing changes) for a stamp not after the last scan's (or past the horizon from it, but for
        a stream back after a gap), or further than the horizon either way from the wheel-angle time
        ``wheel_ns`` (None: none yet)."""
        stamp_ns = scan.tm.to_nanoseconds()
        if self._taken_ns is not None:
            self._gap.check(stamp_ns, self._taken_ns)
        if wheel_ns is not None:
            check_stamp_near(stamp_ns, wheel_ns, self._horizon_ns, self._horizon_ns, "scan")
        self._pending.append((stamp_ns, ScanPoints.from_scan(scan, self.geometry)))
        self._taken_ns = stamp_ns
        self.scans += 1
        self.scan_rays += len(scan.ranges)

    def _apply_scans_before(self, stamp_ns: int) -> None:
        """Make the scans taken with a stamp before ``stamp_ns`` the monitor's, in order."""
        pending = self._pending
        while pending and pending[0][0] < stamp_ns:
            scan_ns, points = pending.popleft()
            self._points, self.scan_ns, self._judged = points, scan_ns, False
            self.nearest = points.nearest()

    def forget(self) -> None:
        """A new time base (a restarted simulator): no scan yet, no hold."""
        self._points = self.scan_ns = self.nearest = self._taken_ns = None
        self._pending.clear()
        self._judged = False
        self.verdict, self._factor, self._slowed = CLEAR, 1.0, False
        self._release()

    def factor(self, stamp_ns: int, vx: float, w: float) -> float:
        """What the command (vx, w) of the cycle stamped ``stamp_ns`` is multiplied by (called at
        every cycle: floats and a stamp unless the scan or the command changed). The scans stamped
        before ``stamp_ns`` apply first: a step's scan, published after its torque, from
        the next step's cycle on, whichever of the two the motor takes first."""
        if self._pending and self._pending[0][0] < stamp_ns:
            self._apply_scans_before(stamp_ns)
        scan_ns = self.scan_ns
        if scan_ns is None:
            return 1.0
        if stamp_ns - scan_ns > self._timeout_ns:
            if self._cause is None or self._cause[0] != STALE_SCAN:
                self._hold(
                    (STALE_SCAN, ""),
                    stamp_ns,
                    f"no scan for {(stamp_ns - scan_ns) / NANOSECONDS_PER_SECOND:.2f} s "
                    f"(collision_monitor.scan_timeout {self.settings.scan_timeout:g} s)",
                )
                self._judged = False
            return 0.0
        if not self._judged or vx != self._vx or w != self._w:
            self._judge(stamp_ns, vx, w)
        return self._factor

    def _judge(self, stamp_ns: int, vx: float, w: float) -> None:
        assert self._points is not None
        verdict = judge(self._points, vx, w, self.geometry)
        self.verdict, self._vx, self._w, self._judged = verdict, vx, w, True
        if verdict.zone is Zone.STOP:
            self._factor = 0.0
            body = verdict.obstacle.body if verdict.obstacle is not None else ""
            if self._cause != (OBSTACLE, body):
                self._hold((OBSTACLE, body), stamp_ns, verdict.describe(vx))
            self._slowed = False
            return
        self._release()
        slowed = verdict.zone is Zone.SLOW
        self.slowdowns += slowed and not self._slowed
        self._slowed = slowed
        self._factor = self._slow_factor if slowed else 1.0

    def _hold(self, cause: tuple[str, str], stamp_ns: int, held_by: str) -> None:
        if self._cause is None:
            self.holds += 1
            self.holds_by[cause[0]] += 1
            self.held_since_ns = stamp_ns
        elif self._cause[0] != cause[0]:
            self.holds_by[cause[0]] += 1
        self._cause, self.held_by = cause, held_by

    def _release(self) -> None:
        self._cause, self.held_by, self.held_since_ns = None, "", None

    def status(self, bad_scans: int) -> CollisionMonitorStatus:
        """Its settings, what it sees now and its counters (``bad_scans``: the node counts them)."""
        settings, nearest = self.settings, self.nearest
        return CollisionMonitorStatus(
            enabled=True,
            stop_distance=settings.stop_distance,
            slow_distance=settings.slow_distance,
            slow_factor=settings.slow_factor,
            margin=settings.margin,
            scan_timeout=settings.scan_timeout,
            min_points=settings.min_points,
            monitoring=self.scan_ns is not None,
            held_by=self.held_by,
            zone=str(self.verdict.zone),
            factor=self._factor if self.scan_ns is not None else 1.0,
            last_scan_s=None if self.scan_ns is None else self.scan_ns / NANOSECONDS_PER_SECOND,
            nearest=None
            if nearest is None
            else NearestObstacle(nearest.body, round(nearest.clearance, 4), nearest.x, nearest.y),
            counters=CollisionCounters(
                scans=self.scans,
                scan_rays=self.scan_rays,
                holds=self.holds,
                holds_by=dict(self.holds_by),
                slowdowns=self.slowdowns,
                bad_scans=bad_scans,
            ),
        )
