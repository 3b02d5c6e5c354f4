"""``invent localization`` with ``localization.mode = "amcl"``: the particle filter of
:mod:`services.localization.amcl` on the map of ``navigation.map``, fed the lidar's scans
(``sim/scan``) and the wheel angles (``motor/wheel_angles``), which it integrates itself with the
odometry's core: its motion model never depends on when the odometry took a fix. It reads no ground
truth (docs/localization.md).

At every tick of ``localization.rate`` (simulation time, as the stub's) it publishes the estimate on
``localization/pose`` with its covariance in ``error`` (xx, xy, xθ, yy, yθ, θθ); the odometry resets
from it, as from the stub's fixes. The particles start around the initial pose; the first fix (at
time 0) has already taken the first scan.
Its particles go on ``localization/particles`` at ``localization.particles_rate``.

Lockstep: a tick is published once the scans due by then (the lidar's grid, anchored at 0, as the
simulator casts them) have arrived, waiting in the scan input at most ``sim.lockstep_timeout`` wall
seconds (a scan later than that is counted, ``scans_late``): a tick's estimate is the same on a busy
or a quiet machine.

``localization/initial_pose`` seeds the filter again around the pose given (RViz's "2D Pose
Estimate", through the ROS 2 bridge's ``/initialpose``), ``localization/global_localization`` spreads
the particles over the map's free cells; both are taken at once, whenever they come.
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np

from schemas.codec import BadInput, BadMessage, decode
from schemas.messages import NANOSECONDS_PER_SECOND, LaserScan, NoArguments, Time, TimedDoubleSeq, TimedPosition
from schemas.navigation import InitialPose, LocalizationReply, ParticleCloud
from schemas.status import AmclEstimate, AmclFilterStatus, LocalizationFix, LocalizationStatus, PlanarPose
from services.clock.sim_time import PeriodicSchedule, StampClock
from services.clock.sim_watch import SimulatorWatch
from services.config import Config, ConfigError
from services.localization.amcl import ParticleFilter
from services.localization.core import resolve_seed
from services.localization.likelihood import LikelihoodField
from services.navigation.map_file import read_map
from services.odometry.core import Odometry
from services.planar import Pose, check_coordinates
from services.runtime.inputs import Delivery
from services.runtime.node import Node, Wait

ODOMETRY_HISTORY = 512
"""Wheel-angle steps kept to place a scan that arrives after later steps (half a second at 1 kHz)."""
PENDING_SCANS = 16
"""Scans kept until a wheel-angle step at or after their stamp places them (beyond: the oldest dropped)."""


def covariance_values(covariance: np.ndarray) -> list[float]:
    """A 3 × 3 covariance as ``localization/pose`` sends it: its upper triangle, row by row."""
    return [float(covariance[row, col]) for row in range(3) for col in range(row, 3)]


def covariance_matrix(values: list[float]) -> np.ndarray:
    """The 3 × 3 symmetric covariance of an upper triangle as sent (:func:`covariance_values`)."""
    matrix = np.zeros((3, 3))
    entries = iter(values)
    for row in range(3):
        for col in range(row, 3):
            matrix[row, col] = matrix[col, row] = next(entries)
    return matrix


class AmclLocalization:
    finished = False
    """It serves until stopped."""
    exit_code = 0

    def __init__(self, node: Node, config: Config) -> None:
        if config.navigation.map is None:
            raise ValueError("localization.mode = amcl needs a map (navigation.map)")
        self.node = node
        self.config = config.localization
        self.lidar = config.lidar
        self.seed = resolve_seed(self.config.seed)
        grid = read_map(config.navigation.map)
        self.filter = ParticleFilter(
            LikelihoodField(grid, config.amcl.likelihood_max_dist),
            config.amcl,
            config.lidar,
            np.random.default_rng(self.seed),
        )
        self.initial = Pose(self.config.initial_x, self.config.initial_y, self.config.initial_theta)
        try:
            self.filter.seed(self.initial, None)
        except BadInput as error:
            raise ConfigError(f"localization.initial_x, initial_y: {error}") from None
        self.odometry = Odometry(config.robot, config.odometry, start=self.initial, limits=config.input)
        self._max_coordinate = config.input.max_coordinate
        self._clock = StampClock(config.input.stamp_horizon_ns)
        self._history: deque[tuple[int, Pose]] = deque(maxlen=ODOMETRY_HISTORY)
        self._scans: deque[LaserScan] = deque()
        self._last_scan_ns: int | None = None
        self._schedule: PeriodicSchedule | None = None
        self._particle_schedule: PeriodicSchedule | None = None
        self._scan_grid = PeriodicSchedule(config.lidar.rate, 0) if config.lidar.enabled else None
        self._last_scan_tick_ns: int | None = None
        """The lidar's last grid tick passed: a scan stamped there or later is owed."""
        self._due_scan_ns: int | None = None
        """The stamp a scan must be at or after for the pending tick to be published."""
        self._pending_tick: tuple[int, float] | None = None
        """A tick (stamp, wall deadline) waiting for its scan."""
        self._lockstep_timeout = config.sim.lockstep_timeout
        self.counters = dict.fromkeys(
            (
                "fixes",
                "scans",
                "scans_late",
                "scans_dropped",
                "scans_without_odometry",
                "initial_poses",
                "global_localizations",
            ),
            0,
        )
        self.last_fix: TimedPosition | None = None
        self.publisher = node.publisher(node.keys.localization_pose)
        self.particles = node.publisher(node.keys.localization_particles)
        node.participate(self.publisher, self.config.rate)
        self.sim = SimulatorWatch(node, self._clock.restart)
        self._wheels = node.subscribe(
            node.keys.motor_wheel_angles,
            TimedDoubleSeq,
            self.sim.clock(self._on_wheel_angles),
            Delivery.EVERY,
            wakes=True,
        )
        self._scan_input = node.subscribe(
            node.keys.sim_scan,
            LaserScan,
            self.sim.stamped(node.keys.sim_scan, self._on_scan, awaited=lambda: self._pending_tick is not None),
            Delivery.EVERY,
        )
        node.queryable(node.keys.localization_initial_pose, self._on_initial_pose, mutates=True)
        node.queryable(node.keys.localization_global_localization, self._on_global_localization, mutates=True)
        node.wait_with(self._next_wait)
        node.set_status(self.status)
        node.log.info(
            "amcl on %s: %d to %d particles, fixes at %g Hz of simulation time, seed %d",
            config.navigation.map,
            config.amcl.min_particles,
            config.amcl.max_particles,
            self.config.rate,
            self.seed,
        )

    def _on_scan(self, scan: LaserScan) -> None:
        stamp_ns = scan.tm.to_nanoseconds()
        if len(scan.ranges) != self.lidar.rays:
            raise BadInput(f"{len(scan.ranges)} ranges, the lidar has {self.lidar.rays} rays")
        if self._last_scan_ns is not None and stamp_ns <= self._last_scan_ns:
            raise BadInput(f"scan stamped {stamp_ns / NANOSECONDS_PER_SECOND:.6g} s, not after the last one")
        self._last_scan_ns = stamp_ns
        if len(self._scans) == PENDING_SCANS:
            self._scans.popleft()
            self.counters["scans_dropped"] += 1
        self._scans.append(scan)
        if self._pending_tick is not None:
            self._complete_tick()
        elif self._history:
            self._take_scans(self._history[-1][0])

    def _on_wheel_angles(self, sample: TimedDoubleSeq) -> None:
        stamp_ns = sample.tm.to_nanoseconds()
        if self._clock.advance(stamp_ns):
            self._new_time_base()
        if self._pending_tick is not None:
            self._complete_tick(stepped_on=True)  # a later sample: the simulator gave up waiting
        step = self.odometry.step(stamp_ns, sample.data)
        self._history.append((stamp_ns, Pose(step.x, step.y, step.theta)))
        self._take_scans(stamp_ns)
        self._tick(stamp_ns)

    def _new_time_base(self) -> None:
        """A restarted simulator: its clock and wheel angles start again; the particles are kept
        (the robot's pose is not known to have changed; the random particles find it if it has)."""
        self.node.log.info("simulation time went back (a new simulator): a new time base")
        self.odometry.restart_time_base()
        self._history.clear()
        self._scans.clear()
        self._last_scan_ns = None
        self._pending_tick = None
        self._schedule = self._particle_schedule = None
        self._scan_grid = PeriodicSchedule(self.lidar.rate, 0) if self.lidar.enabled else None
        self._last_scan_tick_ns = None

    def _take_scans(self, until_ns: int) -> None:
        """Update the filter with every scan stamped at or before ``until_ns``, each placed by the
        wheels' pose at its stamp."""
        while self._scans and self._scans[0].tm.to_nanoseconds() <= until_ns:
            scan = self._scans.popleft()
            self.node.guard(self.node.keys.sim_scan, self._update, scan)

    def _update(self, scan: LaserScan) -> None:
        stamp_ns = scan.tm.to_nanoseconds()
        pose = next((pose for stamp, pose in reversed(self._history) if stamp <= stamp_ns), None)
        if pose is None:
            self.counters["scans_without_odometry"] += 1
            return
        self.filter.motion(pose)
        ranges = np.array([math.inf if value is None else value for value in scan.ranges])
        self.filter.update(ranges, scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max)
        self.counters["scans"] += 1

    def _tick(self, stamp_ns: int) -> None:
        if self._schedule is None:
            if not self.publisher.matched:
                return  # the initial pose must reach the odometry: the schedule starts once someone listens
            self._schedule = PeriodicSchedule(self.config.rate, 0)
            if self.config.particles_rate > 0.0:
                self._particle_schedule = PeriodicSchedule(self.config.particles_rate, 0)
        if self._particle_schedule is not None and self._particle_schedule.due(stamp_ns):
            self._publish_particles(stamp_ns)
        if not self._schedule.due(stamp_ns):
            return
        due = self._last_scan_due(stamp_ns)
        if self.node.participating and due is not None and (self._last_scan_ns is None or self._last_scan_ns < due):
            self._due_scan_ns = due
            self._pending_tick = (stamp_ns, time.monotonic() + self._lockstep_timeout)
            return
        self._publish_fix(stamp_ns)

    def _last_scan_due(self, stamp_ns: int) -> int | None:
        """The stamp of the lidar's last grid tick at or before ``stamp_ns`` (a scan stamped there or
        later is owed by then), None without a lidar or before its first."""
        grid = self._scan_grid
        if grid is None:
            return None
        while grid.next_ns <= stamp_ns:
            self._last_scan_tick_ns = grid.next_ns
            grid.due(grid.next_ns)
        return self._last_scan_tick_ns

    def _complete_tick(self, stepped_on: bool = False) -> None:
        """Publish the pending tick's fix once its scan has come, its wait is over, or the simulator
        stepped on without it (composed, nothing calls :meth:`_next_wait`: the inputs' handlers do)."""
        pending = self._pending_tick
        if pending is None:
            return
        stamp_ns, deadline = pending
        arrived = (
            self._last_scan_ns is not None and self._due_scan_ns is not None and self._last_scan_ns >= self._due_scan_ns
        )
        if not arrived and not stepped_on and time.monotonic() < deadline:
            return
        if not arrived:
            self.counters["scans_late"] += 1
        self._pending_tick = None
        self._take_scans(stamp_ns)
        self._publish_fix(stamp_ns)
        if self._history and self._history[-1][0] > stamp_ns:
            self._take_scans(self._history[-1][0])

    def _next_wait(self) -> Wait:
        self._complete_tick()
        if self._pending_tick is not None:
            return Wait(self._scan_input, until=self._pending_tick[1])
        return Wait(self._wheels)

    def _publish_fix(self, stamp_ns: int) -> None:
        estimate = self.filter.estimate()
        x, y, theta = estimate.pose
        fix = TimedPosition(
            tm=Time.from_nanoseconds(stamp_ns),
            id=[],
            x=x,
            y=y,
            theta=theta,
            error=covariance_values(estimate.covariance),
        )
        self.publisher.put(fix)
        self.last_fix = fix
        self.counters["fixes"] += 1

    def _publish_particles(self, stamp_ns: int) -> None:
        particles = self.filter
        xs, ys, thetas, weights = particles.xs, particles.ys, particles.thetas, particles.weights
        self.particles.put(
            ParticleCloud(
                tm=Time.from_nanoseconds(stamp_ns),
                x=xs.tolist(),
                y=ys.tolist(),
                theta=thetas.tolist(),
                weight=weights.tolist(),
            )
        )

    def _on_initial_pose(self, payload: bytes) -> LocalizationReply:
        try:
            request = decode(InitialPose, payload)
            check_coordinates(request.x, request.y, self._max_coordinate)
            covariance = covariance_matrix(request.covariance) if request.covariance else None
            self.filter.seed(Pose(request.x, request.y, request.theta), covariance)
        except BadInput as error:
            self.node.bad_inputs.record(self.node.keys.localization_initial_pose, str(error))
            kind = "not an InitialPose" if isinstance(error, BadMessage) else "refused"
            return LocalizationReply(False, f"{kind}: {error}")
        self.counters["initial_poses"] += 1
        self.node.log.info("seeded again around (%g, %g, %g)", request.x, request.y, request.theta)
        return LocalizationReply(True)

    def _on_global_localization(self, payload: bytes) -> LocalizationReply:
        try:
            if payload.strip():
                decode(NoArguments, payload)
        except BadMessage as error:
            self.node.bad_inputs.record(self.node.keys.localization_global_localization, str(error))
            return LocalizationReply(False, f"not empty arguments: {error}")
        self.filter.global_localization()
        self.counters["global_localizations"] += 1
        self.node.log.info("particles spread over the map's free cells")
        return LocalizationReply(True)

    def status(self) -> LocalizationStatus:
        estimate = self.filter.estimate()
        fix = self.last_fix
        return LocalizationStatus(
            state="running" if self._schedule is not None else "waiting_for_subscriber",
            mode="amcl",
            sim_alive=self.sim.alive,
            rate_hz=self.config.rate,
            seed=self.seed,
            seed_from_config=self.config.seed is not None,
            initial_pose=PlanarPose(*self.initial),
            estimate=AmclEstimate(*estimate.pose, covariance=covariance_values(estimate.covariance)),
            last_fix=None
            if fix is None
            else LocalizationFix(fix.tm.to_nanoseconds() / NANOSECONDS_PER_SECOND, fix.x, fix.y, fix.theta),
            filter=AmclFilterStatus(
                particles=int(self.filter.xs.size),
                updates=self.filter.updates,
                resamples=self.filter.resamples,
                recoveries=self.filter.recoveries,
                random_particles=self.filter.random_particles,
                jumps=self.filter.jumps,
                last_jump=self.filter.last_jump,
            ),
            counters=dict(self.counters),
            time_base_restarts=self._clock.restart.restarts,
            lockstep_participant=self.node.participating,
        )

    def close(self) -> None:
        """Nothing beyond the node to release."""
