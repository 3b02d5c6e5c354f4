"""A map built from scans and odometry, each scan's pose corrected by matching it against the map
built so far (pure: numpy).

Feed :class:`MapBuilder` the odometry's poses (:meth:`MapBuilder.add_odometry`) and the lidar's scans
(:meth:`MapBuilder.add_scan`) in time order, as a recording holds them or as they come live. A scan
waits until the odometry reaches its stamp; the odometry pose at the scan's stamp is interpolated
between the two poses around it. The odometry drifts but is precise over the 0.1 s between two scans:
the **prior** of a scan is the last corrected pose moved by the odometry's motion since that scan,
and the scan is matched from there against the map so far (:mod:`services.mapping.matcher`). A
trusted match (enough of its points on the map) gives the scan's corrected pose, an untrusted one
(the map does not reach there yet: the first scans, a new room seen through a door) keeps the
prior. The scan is then traced into the grid (:mod:`services.mapping.occupancy`) from that pose.
A finished map (a recording's: :mod:`services.mapping.from_recording`) is then put where the run
started (:meth:`MapBuilder.anchor`); a live one grows as it is.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from schemas.messages import LaserScan
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE
from services.config.sensors import LidarConfig
from services.mapping.matcher import Match, MatcherSettings, SurfaceField, match, transform
from services.mapping.occupancy import LogOddsGrid
from services.navigation.grid import Grid
from services.planar import Pose, compose, inverse, relative_motion, wrap_angle

Floats = npt.NDArray[np.float64]

DEFAULT_RESOLUTION = 0.05
"""m: a map's cell by default (the navigation's)."""
MAX_ODOMETRY_SPEED = 0.6
"""m/s: faster than the drive's wheels take the robot (``drive.cruise_speed`` 0.3); an odometry step
faster than this (beyond :data:`ODOMETRY_STEP_SLACK`) is a reset, not motion."""
ODOMETRY_STEP_SLACK = 0.005
"""m: a step's allowance beyond :data:`MAX_ODOMETRY_SPEED` (the poses' stamps are rounded)."""
MAX_ODOMETRY_TURN_RATE = 2.0
"""rad/s: likewise for turns (``drive.max_turn_rate`` 1 rad/s)."""
ODOMETRY_TURN_SLACK = 0.01
"""rad: a turn's allowance beyond :data:`MAX_ODOMETRY_TURN_RATE`."""
MAX_ODOMETRY_GAP_S = 0.5
"""s: a scan later than the last odometry pose by up to this takes that pose; later, it is dropped
(the odometry stopped)."""


@dataclass(frozen=True)
class LidarMount:
    """Where the lidar sits on the base frame (the axle centre): ``LidarConfig``'s x, y, yaw."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    @classmethod
    def of(cls, lidar: LidarConfig) -> LidarMount:
        return cls(lidar.x, lidar.y, lidar.yaw)


CENTRED = LidarMount()
"""The lidar at the axle centre, looking ahead (``LidarConfig``'s defaults)."""
DEFAULT_SETTINGS = MatcherSettings()
ANCHOR_SCANS = 10
"""The first scans (a second at the lidar's 10 Hz) that fix a finished map's frame (:meth:`MapBuilder.anchor`)."""
ANCHOR_SETTINGS = MatcherSettings(prior_xy_sigma=0.05, prior_theta_sigma=math.radians(3.0))
"""A first scan matched again against the finished map: its prior (the pose it was traced from) is
off by the map's drift since, not by a scan's worth of motion."""


@dataclass(frozen=True)
class ScanPose:
    """One scan's poses: what the odometry said at its stamp, and the corrected pose it was traced from."""

    stamp_ns: int
    odometry: Pose
    corrected: Pose
    matched: bool
    """Whether a trusted match gave ``corrected`` (else it is the prior)."""


@dataclass
class Counters:
    scans: int = 0
    """Scans traced into the map."""
    matched: int = 0
    """Of those, the ones a trusted match corrected."""
    before_odometry: int = 0
    """Scans dropped: stamped before the first odometry pose."""
    after_odometry: int = 0
    """Scans dropped: stamped more than :data:`MAX_ODOMETRY_GAP_S` after the last odometry pose."""
    outside: int = 0
    """Scans dropped: the grid would pass its bound on cells a side to hold them."""
    empty: int = 0
    """Scans with no usable ray."""
    odometry_resets: int = 0
    """Odometry steps no robot drives (a localization's fix), taken out of the priors' motion."""


@dataclass
class _Odometry:
    """The odometry's poses so far, by stamp, made continuous: a step no robot drives in the time
    between two poses (a localization fix the odometry was reset to) is taken out, the poses after
    it moved back by it, so that a scan's prior is the wheels' motion and not the fix's correction."""

    stamps: list[int] = field(default_factory=list)
    poses: list[Pose] = field(default_factory=list)
    jumps: int = 0
    """Steps taken out as resets."""
    _offset: Pose = Pose(0.0, 0.0, 0.0)
    """What the resets so far moved the odometry by: a pose as given, composed after it."""

    def add(self, stamp_ns: int, pose: Pose) -> None:
        if self.stamps and stamp_ns < self.stamps[-1]:
            raise ValueError(
                f"odometry pose at {stamp_ns} ns after one at {self.stamps[-1]} ns: feed them in time order"
            )
        continuous = compose(self._offset, pose)
        if self.poses:
            previous = self.poses[-1]
            seconds = (stamp_ns - self.stamps[-1]) / 1e9
            step = relative_motion(previous, continuous)
            if (
                math.hypot(step.x, step.y) > MAX_ODOMETRY_SPEED * seconds + ODOMETRY_STEP_SLACK
                or abs(step.theta) > MAX_ODOMETRY_TURN_RATE * seconds + ODOMETRY_TURN_SLACK
            ):
                self._offset = compose(previous, inverse(pose))
                continuous = previous
                self.jumps += 1
        self.stamps.append(stamp_ns)
        self.poses.append(continuous)

    def at(self, stamp_ns: int) -> Pose:
        """The pose at ``stamp_ns`` within the poses' span, interpolated linearly (the heading the short way)."""
        after = bisect.bisect_left(self.stamps, stamp_ns)
        if after < len(self.stamps) and self.stamps[after] == stamp_ns:
            return self.poses[after]
        t0, t1 = self.stamps[after - 1], self.stamps[after]
        p0, p1 = self.poses[after - 1], self.poses[after]
        share = (stamp_ns - t0) / (t1 - t0)
        return Pose(
            p0.x + share * (p1.x - p0.x),
            p0.y + share * (p1.y - p0.y),
            wrap_angle(p0.theta + share * wrap_angle(p1.theta - p0.theta)),
        )

    def drop_before(self, stamp_ns: int) -> None:
        """Forget the poses no later scan can need (all but the last at or before ``stamp_ns``)."""
        keep = max(bisect.bisect_right(self.stamps, stamp_ns) - 1, 0)
        del self.stamps[:keep], self.poses[:keep]


class MapBuilder:
    """An occupancy grid and each scan's corrected pose, from odometry poses and scans in time order."""

    def __init__(
        self,
        resolution: float = DEFAULT_RESOLUTION,
        mount: LidarMount = CENTRED,
        settings: MatcherSettings = DEFAULT_SETTINGS,
        max_cells_per_side: int = MAX_COSTMAP_CELLS_PER_SIDE,
    ) -> None:
        self.mount = mount
        self.settings = settings
        self.occupancy = LogOddsGrid(resolution, max_cells_per_side)
        self.poses: list[ScanPose] = []
        self.counters = Counters()
        self._odometry = _Odometry()
        self._pending: list[LaserScan] = []
        self._last: ScanPose | None = None

    def add_odometry(self, stamp_ns: int, pose: Pose) -> None:
        """An odometry pose (the axle centre's, in ``odom``); traces the scans it lets through."""
        self._odometry.add(stamp_ns, pose)
        self.counters.odometry_resets = self._odometry.jumps
        while self._pending and self._pending[0].tm.to_nanoseconds() <= stamp_ns:
            self._trace(self._pending.pop(0))

    def add_scan(self, scan: LaserScan) -> None:
        """A scan: traced now if the odometry reached its stamp, else when it does."""
        stamp_ns = scan.tm.to_nanoseconds()
        stamps = self._odometry.stamps
        if not stamps or stamp_ns < stamps[0]:
            self.counters.before_odometry += 1
        elif stamp_ns <= stamps[-1] and not self._pending:
            self._trace(scan)
        else:
            self._pending.append(scan)

    def finish(self) -> None:
        """The odometry has ended: trace the scans waiting for it that are close enough to its last pose."""
        stamps = self._odometry.stamps
        for scan in self._pending:
            if scan.tm.to_nanoseconds() - stamps[-1] <= MAX_ODOMETRY_GAP_S * 1e9:
                self._trace(scan, self._odometry.poses[-1])
            else:
                self.counters.after_odometry += 1
        self._pending.clear()

    def grid(self) -> Grid:
        """The map so far: free 0, occupied 100, unknown -1."""
        return self.occupancy.grid()

    def _trace(self, scan: LaserScan, odometry: Pose | None = None) -> None:
        stamp_ns = scan.tm.to_nanoseconds()
        if odometry is None:
            odometry = self._odometry.at(stamp_ns)
            self._odometry.drop_before(stamp_ns)
        ends, hit = scan_points(scan, self.mount)
        if not len(ends):
            self.counters.empty += 1
            return
        prior = odometry if self._last is None else _moved(self._last.corrected, self._last.odometry, odometry)
        result = self._match(ends[hit], prior, scan.range_max, self.settings)
        matched = result is not None and result.trusted(self.settings)
        corrected = result.pose if matched and result is not None else prior
        if not _insert(self.occupancy, self.mount, corrected, ends, hit):
            self.counters.outside += 1
            return
        self._last = ScanPose(stamp_ns, odometry, corrected, matched)
        self.poses.append(self._last)
        self.counters.scans += 1
        self.counters.matched += matched

    def anchor(self, scans: Sequence[LaserScan]) -> Pose | None:
        """Put the finished map where the run started: the first :data:`ANCHOR_SCANS` scans traced are
        matched again, against the whole map now, and every pose is moved by the transform that puts
        them back on the odometry's poses at their stamps (the median of theirs); the grid is then
        traced again from the moved poses. ``scans``: the scans fed (the traced ones are found by
        stamp). The transform, or None when no first scan matched (nothing is moved).

        The first scans' odometry is the run's start, good to a millimetre over the first second; their
        matches at the time were against a map of a few scans, whose small biases turned and moved
        the map a little (the three_rooms tour: 0.27° and 1.3 cm, 2 cm at the far room). Matched
        against the finished map, they say where its frame lies against the start."""
        by_stamp = {scan.tm.to_nanoseconds(): scan for scan in scans}
        moves = []
        for pose in self.poses[:ANCHOR_SCANS]:
            scan = by_stamp[pose.stamp_ns]
            ends, hit = scan_points(scan, self.mount)
            result = self._match(ends[hit], pose.corrected, scan.range_max, ANCHOR_SETTINGS)
            if result is not None and result.trusted(ANCHOR_SETTINGS):
                moves.append(compose(pose.odometry, inverse(result.pose)))
        if not moves:
            return None
        move = Pose(
            float(np.median([m.x for m in moves])),
            float(np.median([m.y for m in moves])),
            float(np.median([m.theta for m in moves])),
        )
        self.retrace(move, scans)
        return move

    def retrace(self, move: Pose, scans: Sequence[LaserScan]) -> None:
        """Move every corrected pose by ``move`` (composed before it: a move of the map's frame) and
        trace the grid again from the moved poses; ``scans``: the scans fed, found by stamp."""
        by_stamp = {scan.tm.to_nanoseconds(): scan for scan in scans}
        occupancy = LogOddsGrid(self.occupancy.resolution, self.occupancy.max_cells_per_side)
        moved = []
        for pose in self.poses:
            corrected = compose(move, pose.corrected)
            ends, hit = scan_points(by_stamp[pose.stamp_ns], self.mount)
            if _insert(occupancy, self.mount, corrected, ends, hit):
                moved.append(ScanPose(pose.stamp_ns, pose.odometry, corrected, pose.matched))
            else:  # moved past the grid's bound, at its edge
                self.counters.outside += 1
                self.counters.scans -= 1
                self.counters.matched -= pose.matched
        self.occupancy, self.poses = occupancy, moved
        self._last = moved[-1] if moved else None

    def _match(self, points: Floats, prior: Pose, range_max: float, settings: MatcherSettings) -> Match | None:
        """The scan's returns matched against the map so far near ``prior``; None with too little of either."""
        if len(points) < settings.min_points or self.occupancy.empty:
            return None
        radius = range_max + math.hypot(self.mount.x, self.mount.y)
        field = SurfaceField.around(self.occupancy, prior.x, prior.y, radius, settings.max_distance)
        return None if field is None else match(points, (self.mount.x, self.mount.y), prior, field, settings)


def _insert(occupancy: LogOddsGrid, mount: LidarMount, pose: Pose, ends: Floats, hit: npt.NDArray[np.bool_]) -> bool:
    """Trace a scan's rays (base frame) into ``occupancy`` from the base at ``pose``; False, and nothing
    traced, when the grid would pass its bound to hold them."""
    lidar_x, lidar_y = transform(pose, np.array([[mount.x, mount.y]]))
    end_x, end_y = transform(pose, ends)
    if not occupancy.cover(
        min(float(end_x.min()), float(lidar_x[0])),
        min(float(end_y.min()), float(lidar_y[0])),
        max(float(end_x.max()), float(lidar_x[0])),
        max(float(end_y.max()), float(lidar_y[0])),
    ):
        return False
    occupancy.insert(float(lidar_x[0]), float(lidar_y[0]), end_x, end_y, hit)
    return True


def scan_points(scan: LaserScan, mount: LidarMount) -> tuple[Floats, npt.NDArray[np.bool_]]:
    """A scan in the base frame: ``(ends, hit)``, where each usable ray ends (``[n, 2]``: its return, or
    ``range_max`` along it when it has none) and which of them returned. A ray below ``range_min`` is
    not usable."""
    ranges = np.array([math.inf if value is None else value for value in scan.ranges], dtype=np.float64)
    angles = mount.yaw + scan.angle_min + scan.angle_increment * np.arange(len(ranges))
    no_return = ~(ranges <= scan.range_max)
    usable = no_return | (ranges >= scan.range_min)
    length = np.where(no_return, scan.range_max, ranges)[usable]
    angles = angles[usable]
    ends = np.stack((mount.x + length * np.cos(angles), mount.y + length * np.sin(angles)), axis=1)
    return ends, ~no_return[usable]


def _moved(corrected: Pose, odometry_then: Pose, odometry_now: Pose) -> Pose:
    """``corrected`` moved by the odometry's motion from ``odometry_then`` to ``odometry_now`` (in the
    robot's frame then: the drift of the odometry's heading does not turn the motion)."""
    dx, dy = odometry_now.x - odometry_then.x, odometry_now.y - odometry_then.y
    cos, sin = math.cos(odometry_then.theta), math.sin(odometry_then.theta)
    forward, left = cos * dx + sin * dy, -sin * dx + cos * dy
    cos, sin = math.cos(corrected.theta), math.sin(corrected.theta)
    return Pose(
        corrected.x + cos * forward - sin * left,
        corrected.y + sin * forward + cos * left,
        wrap_angle(corrected.theta + wrap_angle(odometry_now.theta - odometry_then.theta)),
    )
