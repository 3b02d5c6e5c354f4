"""The drive's navigation on zenoh (goal mode with ``navigation.enabled``): docs/navigation.md.

The shell of the costmap (services/navigation/costmap.py): it loads the map (``navigation.map``),
publishes it on ``drive/map`` (latched) at the first tick, takes every ``sim/scan`` (each into the
costmap at the first tick at or after its stamp, from the robot's pose at that stamp and the lidar's
mount), publishes the costmap on ``drive/costmap`` at ``navigation.costmap_rate``, and each goal's plan
on ``drive/plan`` (latched: at every new plan, empty when the goal ends).

Lockstep: a tick takes the scans stamped at or before it. The simulator publishes a step's scan
before that step's clock, from one session, so the scan is in this input's queue when the clock
that makes the tick arrives (zenoh keeps one publisher session's samples in order, and a composed
bus hands them over at once); a scan that comes after its tick's command is counted (``scans_late``)
and taken at the next tick: a run that shows any is not deterministic.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque

from schemas.codec import BadInput
from schemas.drive_status import DriveNavigationStatus
from schemas.messages import NANOSECONDS_PER_SECOND, LaserScan, Time
from schemas.navigation import GoalPlan
from services.clock.sim_time import PeriodicSchedule, check_stamp_near
from services.config import Config
from services.mapping.builder import LidarMount, MapBuilder
from services.navigation.costmap import Costmap
from services.navigation.grid import Grid, GridGeometry
from services.navigation.map_file import read_map
from services.planar import Pose
from services.runtime.inputs import Delivery
from services.runtime.node import Node

PENDING_SCANS = 16
"""Scans waiting for their tick (one does, at 10 Hz and 50 Hz ticks); beyond, the oldest is dropped and counted."""
POSE_HISTORY = 64
"""Poses kept to place a scan by its stamp (1.3 s of the drive's ticks at 50 Hz)."""


def costmap_geometry(config: Config, map_grid: Grid | None) -> GridGeometry:
    """The costmap's grid: the map's, else ``navigation.size`` square around the initial pose."""
    if map_grid is not None:
        return map_grid.geometry
    navigation, start = config.navigation, config.odometry
    return GridGeometry.centred(start.initial_x, start.initial_y, navigation.size, navigation.resolution)


class NavigationShell:
    """The costmap's inputs and outputs: call :meth:`pose` with every pose, :meth:`tick` at every tick."""

    def __init__(self, node: Node, config: Config) -> None:
        self.node = node
        settings = config.navigation
        self._map_file = settings.map
        self.map = None if settings.map is None else read_map(settings.map)
        self.costmap = Costmap(
            costmap_geometry(config, self.map),
            settings,
            config.robot.radius_of_body_area,
            None if self.map is None else self.map.cells,
        )
        lidar = config.lidar
        self._mount = (lidar.x, lidar.y, lidar.yaw)
        self.builder = MapBuilder(settings.resolution, LidarMount.of(lidar)) if settings.mapping else None
        """``navigation.mapping``: the map built from the scans as the robot drives."""
        self._horizon_ns = config.input.stamp_horizon_ns
        self._pose_timeout_ns = round(config.drive.pose_timeout * NANOSECONDS_PER_SECOND)
        self._costmap_rate = settings.costmap_rate
        self._costmap_schedule: PeriodicSchedule | None = None
        self._scans: deque[LaserScan] = deque()
        self._poses: deque[tuple[int, Pose]] = deque(maxlen=POSE_HISTORY)
        self._last_scan_ns: int | None = None
        self._last_tick_ns: int | None = None
        self._map_published = False
        self._built_until_ns = -1
        """The newest pose the map builder has (a restarted simulator's poses go on from there)."""
        self._plan_shown: tuple[str, int] | None = None
        self.counters = dict.fromkeys(("scans", "scans_dropped", "scans_late", "scans_without_pose"), 0)
        self._map = node.latched_publisher(node.keys.drive_map)
        self._costmap = node.publisher(node.keys.drive_costmap)
        self._plan = node.latched_publisher(node.keys.drive_plan)
        self._scan_input = node.subscribe(node.keys.sim_scan, LaserScan, self._on_scan, Delivery.EVERY)
        node.log.info(
            "navigation on a costmap of %d x %d cells of %g m from (%.2f, %.2f): %s",
            self.costmap.geometry.width,
            self.costmap.geometry.height,
            self.costmap.geometry.resolution,
            self.costmap.geometry.origin_x,
            self.costmap.geometry.origin_y,
            f"the map {settings.map}" if settings.map is not None else "no map, what the lidar sees",
        )

    def _on_scan(self, scan: LaserScan) -> None:
        stamp_ns = scan.tm.to_nanoseconds()
        if self._last_scan_ns is not None and stamp_ns <= self._last_scan_ns:
            raise BadInput(f"scan stamped {stamp_ns / NANOSECONDS_PER_SECOND:.6g} s, not after the last one")
        if self._last_tick_ns is not None:
            check_stamp_near(stamp_ns, self._last_tick_ns, self._horizon_ns, self._horizon_ns, "scan")
            if stamp_ns <= self._last_tick_ns:
                self.counters["scans_late"] += 1
        self._last_scan_ns = stamp_ns
        if len(self._scans) == PENDING_SCANS:
            self._scans.popleft()
            self.counters["scans_dropped"] += 1
        self._scans.append(scan)

    def pose(self, stamp_ns: int, pose: Pose) -> None:
        """A pose of the robot in ``map`` at ``stamp_ns`` (odometry's)."""
        if self._poses and stamp_ns <= self._poses[-1][0]:
            self._poses.clear()  # a new time base (a restarted simulator): older poses place nothing
        self._poses.append((stamp_ns, pose))
        if self.builder is not None and stamp_ns > self._built_until_ns:
            self.builder.add_odometry(stamp_ns, pose)
            self._built_until_ns = stamp_ns

    def restart(self) -> None:
        """A new simulator (a new run, the robot back at its start): its scans and poses start again,
        and what the old run's lidar saw is forgotten (the map stays)."""
        self.costmap.clear_obstacles()
        self._scans.clear()
        self._poses.clear()
        self._last_scan_ns = self._last_tick_ns = None
        self._costmap_schedule = None

    def tick(self, tick_ns: int) -> bool:
        """Take the scans stamped at or before ``tick_ns`` into the costmap, publish the map (first
        tick) and the costmap (at its rate); True if the costmap took a scan."""
        node = self.node
        while self._scan_input is not None and self._scan_input.take():
            pass  # every scan that arrived before this tick's clock: lockstep's scans, whatever the executor took first
        tm = Time.from_nanoseconds(tick_ns)
        if not self._map_published and self.map is not None:
            self._map.put(self.map.message(tm))
            self._map_published = True
        updated = False
        while self._scans and self._scans[0].tm.to_nanoseconds() <= tick_ns:
            scan = self._scans.popleft()
            node.guard(node.keys.sim_scan, self._mark, scan)
            updated = True
        self._last_tick_ns = tick_ns
        if self._costmap_schedule is None:
            self._costmap_schedule = PeriodicSchedule(self._costmap_rate, 0)
        if self._costmap_schedule.due(tick_ns):
            self._costmap.put(self.costmap.occupancy().message(tm))
            if self.builder is not None and self.builder.counters.scans:
                self._map.put(self.builder.grid().message(tm))
        return updated

    def _mark(self, scan: LaserScan) -> None:
        stamp_ns = scan.tm.to_nanoseconds()
        pose = self._pose_at(stamp_ns)
        if pose is None:
            self.counters["scans_without_pose"] += 1
            return
        x, y, yaw = self._mount
        cos, sin = math.cos(pose.theta), math.sin(pose.theta)
        self.costmap.mark_scan(scan, pose.x + cos * x - sin * y, pose.y + sin * x + cos * y, pose.theta + yaw)
        self.counters["scans"] += 1
        if self.builder is not None:
            self.builder.add_scan(scan)

    def _pose_at(self, stamp_ns: int) -> Pose | None:
        """The latest pose at or before ``stamp_ns``, if it is within ``drive.pose_timeout`` of it."""
        for pose_ns, pose in reversed(self._poses):
            if pose_ns <= stamp_ns:
                return pose if stamp_ns - pose_ns <= self._pose_timeout_ns else None
        return None

    def show_plan(self, tick_ns: int, plan: tuple[str, int, tuple[tuple[float, float], ...]] | None) -> None:
        """Publish the running goal's plan when it changed, an empty one for a goal that had one and ended."""
        shown = self._plan_shown
        if plan is not None:
            goal_id, version, points = plan
            if shown != (goal_id, version):
                self._plan.put(GoalPlan(Time.from_nanoseconds(tick_ns), goal_id, list(points)))
                self._plan_shown = (goal_id, version)
        elif shown is not None:
            self._plan.put(GoalPlan(Time.from_nanoseconds(tick_ns), shown[0], []))
            self._plan_shown = None

    def status(self) -> DriveNavigationStatus:
        mapping = None if self.builder is None else dataclasses.asdict(self.builder.counters)
        return DriveNavigationStatus(
            map=self._map_file, **self.counters, costmap=self.costmap.status(), mapping=mapping
        )
