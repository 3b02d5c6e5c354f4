"""The collision monitor's ``min_points`` (docs/motor.md "Collision monitor", docs/protocol.md
section 4.10; Nav2's rule): a zone acts only on at least ``collision_monitor.min_points`` of a scan's
points, so a stray return does not hold the robot.

Pure: one point fewer than ``min_points`` in the stop zone does not hold and ``min_points`` do,
placed anywhere in the zone of any command (hypothesis); the slow-down zone takes the same rule,
counting the stop zone's points; the obstacle reported is the nearest of the zone's points, never a
nearer one outside it; the geometry still runs only when a scan or the command changes.

On the real services (``invent up --engine kinematic``, lockstep, composed; marked ``slow`` and
``kinematic``): the robot drives 4 s straight at 0.3 m/s past a wall whose face is 0.13 m (2.6 σ)
outside the zones' side, with ``lidar.noise`` = 0.05 m, so that range noise puts one or two of the
wall's returns in the stop zone in some scans: with ``min_points = 1`` they hold the robot, with
the default they do not. Measured over seeds 0 to 4: 9, 2, 6, 9 and 4 of the 41 scans had such
strays; ``min_points = 1`` held the robot 9, 1, 5, 7 and 4 times, the default never. Seed 0 here;
the two runs take a few seconds of wall time.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.keys import Keys, Service
from schemas.messages import NO_HIT, LaserScan, MotorStateReport, Time
from services.config import ConfigError, RobotConfig, load_config
from services.config.sensors import CollisionMonitorConfig, LidarConfig
from services.exits import ExitStatus
from services.motor import monitor as monitor_module
from services.motor.collision import MonitorGeometry, ScanPoints, Zone, in_swept_zone, judge
from services.motor.monitor import CollisionMonitor
from sim_bridge.kinematic_world import Circle, RayCaster
from sim_bridge.sensors import Lidar
from tests.harness import free_port
from tests.test_kinematic_loop import Run, up

NS = 1_000_000_000
DEFAULT = CollisionMonitorConfig()
GEOMETRY = MonitorGeometry.of(RobotConfig(), LidarConfig(), DEFAULT)
R = GEOMETRY.footprint_radius
RAYS = 360


def points(*xy: tuple[float, float]) -> ScanPoints:
    x = np.array([p[0] for p in xy], dtype=np.float64)
    y = np.array([p[1] for p in xy], dtype=np.float64)
    return ScanPoints(x, y, np.zeros(len(xy), dtype=np.intp), ["box"], GEOMETRY.body_radius)


def with_min_points(n: int) -> MonitorGeometry:
    return MonitorGeometry.of(RobotConfig(), LidarConfig(), CollisionMonitorConfig(min_points=n))


def on_the_sweep(vx: float, w: float, travel: float, side: float) -> tuple[float, float]:
    """The point ``side`` × 0.99 R to the left of the axle centre once it has travelled ``travel``
    along the path of (vx, w): inside the zone swept that far."""
    if abs(w) * travel / abs(vx) < 1e-6:
        cx, cy, heading = math.copysign(travel, vx), 0.0, 0.0
    else:
        rho = vx / w
        heading = w * travel / abs(vx)
        cx, cy = rho * math.sin(heading), rho - rho * math.cos(heading)
    return cx - 0.99 * R * side * math.sin(heading), cy + 0.99 * R * side * math.cos(heading)


def face_scan(t: float, count: int, distance: float = 0.76) -> LaserScan:
    """A scan all round (ray 0 backwards) whose ``count`` rays about straight ahead (0, +1, -1, ...)
    see a box's face across the path ``distance`` ahead, and whose 20 rays about straight behind see
    a wall 2 m behind (outside every zone of a forward motion)."""
    ranges: list[float | None] = [None] * RAYS
    for offset in range(-10, 10):
        ranges[offset % RAYS] = 2.0 / math.cos(offset * 2 * math.pi / RAYS)
    for k in range(count):
        offset = (k + 1) // 2 * (1 if k % 2 else -1)
        ranges[RAYS // 2 + offset] = distance / math.cos(offset * 2 * math.pi / RAYS)
    return LaserScan(
        Time.from_nanoseconds(round(t * NS)),
        angle_min=-math.pi,
        angle_increment=2 * math.pi / RAYS,
        range_min=0.12,
        range_max=3.5,
        ranges=ranges,
        bodies=["box"],
        hits=[0] * RAYS,
    )


# --- the setting ------------------------------------------------------------------------------


def test_the_default_needs_more_than_one_point_and_min_points_below_one_is_refused():
    assert DEFAULT.min_points == 4 and GEOMETRY.min_points == 4, "Nav2's default"
    with pytest.raises(ConfigError, match="min_points"):
        load_config(overrides={"collision_monitor.min_points": 0})
    with pytest.raises(ValueError, match="min_points"):
        MonitorGeometry(0.45, 0.05, 0.4, 0.8, min_points=0)


POST_RADIUS = 0.05
"""The thinnest obstacle a robot must see: a post 0.1 m across."""


def post_scan(x: float, y: float) -> LaserScan:
    """The default lidar's noiseless scan, the robot at the origin, of a round post centred at (x, y),
    cast as the kinematic engine casts it."""
    lidar = Lidar(LidarConfig(), RobotConfig().radius_of_body_area, 0)
    caster = RayCaster([Circle("post", x, y, POST_RADIUS, 0.5)], [])
    starts, ends = lidar.rays((0.0, 0.0, 0.0), np.eye(3))
    return lidar.scan(Time.from_nanoseconds(0), caster.cast(0, [], starts, ends), caster.names)


def stop_zone_points(scan: LaserScan) -> int:
    cloud = ScanPoints.from_scan(scan, GEOMETRY)
    return int(np.count_nonzero(in_swept_zone(cloud.x, cloud.y, 0.3, 0.0, R, GEOMETRY.stop_distance)))


@pytest.mark.parametrize("side", [0.0, 0.008, 0.3, RobotConfig().radius_of_body_area + POST_RADIUS])
def test_the_default_holds_on_a_tenth_of_a_metre_post_within_2_4_cm_of_its_first_point(side):
    """The docstring's arithmetic, with the simulator's rays: at the stop zone's far edge, 0.9 m
    ahead (the farthest it reaches from the default lidar), a 0.1 m post takes 6 or 7 rays; as it
    comes nearer (the robot driving straight at it, ``side`` off the path: the last just grazes the
    body), ``min_points`` of its points are in the stop zone at most 2.4 cm after the first is."""
    far = GEOMETRY.stop_distance + R
    assert far == pytest.approx(0.9)
    if side < POST_RADIUS:
        on_post = sum(1 for hit in post_scan(far + POST_RADIUS, side).hits if hit != NO_HIT)
        assert on_post in (6, 7)
    first = held = None
    for mm in range(1000):
        x = far + POST_RADIUS - mm / 1000
        count = stop_zone_points(post_scan(x, side))
        if first is None and count >= 1:
            first = x
        if count >= DEFAULT.min_points:
            held = x
            break
    assert first is not None and held is not None
    assert first - held <= 0.024 + 1e-9, (first, held)
    watcher = CollisionMonitor(RobotConfig(), LidarConfig(), DEFAULT, NS)
    watcher.take_scan(post_scan(held, side), 0)
    assert watcher.factor(1, 0.3, 0.0) == 0.0 and watcher.held_by.startswith("obstacle 'post' in the stop zone")


# --- the rule, pure ---------------------------------------------------------------------------

speeds = st.floats(0.05, 1.5).flatmap(lambda v: st.sampled_from([v, -v]))
turns = st.floats(-2.0, 2.0)
placements = st.lists(st.tuples(st.floats(0.0, 0.39), st.floats(-1.0, 1.0)), min_size=1, max_size=8)


def away(vx: float, count: int) -> list[tuple[float, float]]:
    """``count`` points 3 m and more behind the motion: outside every zone (they reach 0.9 m at most)."""
    return [(-math.copysign(3.0 + 0.1 * k, vx), 0.0) for k in range(count)]


@given(speeds, turns, placements, st.integers(0, 8))
def test_one_point_fewer_than_min_points_in_the_stop_zone_does_not_hold_and_min_points_do(vx, w, where, outside):
    """``len(where)`` points in the stop zone among more outside it (which do not count)."""
    inside = [on_the_sweep(vx, w, travel, side) for travel, side in where]
    n = len(inside)
    cloud = points(*inside, *away(vx, n + 1 + outside))
    assert judge(cloud, vx, w, with_min_points(n)).zone is Zone.STOP, inside
    fewer = judge(cloud, vx, w, with_min_points(n + 1))
    assert fewer.zone is Zone.CLEAR, ("the slow-down zone holds the same points: too few there too", inside)
    assert judge(cloud, 0.0, 0.0, with_min_points(1)).zone is Zone.CLEAR, "no motion, no zone"


def test_the_slow_down_zone_takes_the_same_rule_counting_the_stop_zones_points():
    geometry = with_min_points(3)
    behind = away(0.5, 3)
    stop = [(R + 0.1, 0.0)]
    slow = [(R + 0.5, 0.0), (R + 0.6, 0.1), (R + 0.7, -0.1)]
    assert judge(points(*slow[:2], *behind), 0.5, 0.0, geometry).zone is Zone.CLEAR, "two in the slow-down zone"
    assert judge(points(*slow, *behind), 0.5, 0.0, geometry).zone is Zone.SLOW, "three"
    assert judge(points(*stop, *slow[:2], *behind), 0.5, 0.0, geometry).zone is Zone.SLOW, "one in the stop zone"
    verdict = judge(points(*stop, *slow[:1], *behind), 0.5, 0.0, geometry)
    assert verdict.zone is Zone.CLEAR, "one in each zone: two in the slow-down zone"


@given(speeds, turns, placements)
def test_the_obstacle_reported_is_the_nearest_of_the_zones_points(vx, w, where):
    inside = [on_the_sweep(vx, w, travel, side) for travel, side in where]
    behind = (-math.copysign(R + 0.001, vx), 0.0)  # nearer the body than most, but behind the motion
    cloud = points(*inside, behind)
    verdict = judge(cloud, vx, w, with_min_points(len(inside)))
    assert verdict.zone is Zone.STOP and verdict.obstacle is not None
    mask = in_swept_zone(cloud.x, cloud.y, vx, w, R, GEOMETRY.stop_distance)
    in_zone = {(float(x), float(y)) for x, y in zip(cloud.x[mask], cloud.y[mask], strict=True)}
    assert (verdict.obstacle.x, verdict.obstacle.y) in in_zone
    assert verdict.obstacle.clearance == pytest.approx(float(cloud.clearance[mask].min()))


def test_a_nearer_point_outside_the_zone_is_the_scans_nearest_but_not_the_obstacle():
    behind = (-R - 0.01, 0.0)
    face = [(R + 0.3, y) for y in (-0.02, 0.0, 0.02, 0.04)]
    verdict = judge(points(behind, *face), 0.5, 0.0, GEOMETRY)
    assert verdict.zone is Zone.STOP and verdict.obstacle is not None
    assert (verdict.obstacle.x, verdict.obstacle.y) == (R + 0.3, 0.0)
    nearest = points(behind, *face).nearest()
    assert nearest is not None and nearest.x == -R - 0.01


# --- the monitor ------------------------------------------------------------------------------


def test_the_default_monitor_holds_on_min_points_rays_and_not_on_one_fewer_nor_a_stray():
    watcher = CollisionMonitor(RobotConfig(), LidarConfig(), DEFAULT, NS)
    watcher.take_scan(face_scan(0.0, 1), 0)
    assert watcher.factor(1_000_000, 0.3, 0.0) == 1.0 and watcher.held_by == "", "one stray return"
    watcher.take_scan(face_scan(0.1, DEFAULT.min_points - 1), 100_000_000)
    assert watcher.factor(101_000_000, 0.3, 0.0) == 1.0 and watcher.verdict.zone is Zone.CLEAR
    watcher.take_scan(face_scan(0.2, DEFAULT.min_points), 200_000_000)
    assert watcher.factor(201_000_000, 0.3, 0.0) == 0.0
    assert watcher.held_by == "obstacle 'box' in the stop zone, 0.31 m ahead at (0.76, 0.00) in base_link"
    assert watcher.holds == 1 and watcher.status(bad_scans=0).min_points == DEFAULT.min_points
    one = CollisionMonitor(RobotConfig(), LidarConfig(), CollisionMonitorConfig(min_points=1), NS)
    one.take_scan(face_scan(0.0, 1), 0)
    assert one.factor(1_000_000, 0.3, 0.0) == 0.0 and one.holds == 1, "min_points = 1: any point holds"


def test_the_geometry_runs_only_when_a_scan_or_the_command_changes(monkeypatch):
    calls = []

    def counted(*args, **kwargs):
        calls.append(args[1:3])
        return judge(*args, **kwargs)

    monkeypatch.setattr(monitor_module, "judge", counted)
    watcher = CollisionMonitor(RobotConfig(), LidarConfig(), DEFAULT, NS)
    watcher.take_scan(face_scan(0.0, DEFAULT.min_points - 1), 0)
    for k in range(1, 101):
        watcher.factor(k * 1_000_000, 0.3, 0.0)
    assert len(calls) == 1, "100 cycles of one scan and one command"
    watcher.factor(101_000_000, 0.2, 0.0)
    watcher.take_scan(face_scan(0.1015, DEFAULT.min_points), 101_500_000)
    watcher.factor(102_000_000, 0.2, 0.0)
    assert calls == [(0.3, 0.0), (0.2, 0.0), (0.2, 0.0)]


# --- on the real services, with lidar noise on ------------------------------------------------

KEYS = Keys("rh0")
NOISE_M = 0.05
WALL_GAP_M = 0.13
"""How far outside the zones' side (R = 0.5 m from the path) the wall's face is: 2.6 σ of the noise."""
WORLD = f"""# A wall along the path, its face {WALL_GAP_M} m outside the collision monitor's zones
[[boxes]]
name = "wall"
x = 1.0
y = {R + WALL_GAP_M + 0.05}
size = [4.0, 0.1, 0.5]
"""
SCENARIO = """name = "past the wall"

[[segments]]
type = "constant"
vx = 0.3
w = 0.0
duration = 4.0
"""
"""Straight ahead at the drive's cruise, exactly: the zones are the straight ones every scan."""


def listen() -> tuple[str, str]:
    """A router on a free port: a run beside another on the default port still starts."""
    return "--listen", f"tcp/127.0.0.1:{free_port()}"


def hold_starts(run: Run) -> list[MotorStateReport]:
    """The motor/state reports that start a hold (``counters.holds`` counts the same)."""
    starts, before = [], ""
    for report in run.decoded(KEYS.motor_state, MotorStateReport):
        if report.held_by and not before:
            starts.append(report)
        before = report.held_by
    return starts


def stop_zone_counts(run: Run) -> list[int]:
    """How many of each recorded scan's points lie in the stop zone of the command driven."""
    counts = []
    for scan in run.decoded(KEYS.sim_scan, LaserScan):
        cloud = ScanPoints.from_scan(scan, GEOMETRY)
        inside = in_swept_zone(cloud.x, cloud.y, 0.3, 0.0, R, GEOMETRY.stop_distance)
        counts.append(int(np.count_nonzero(inside)))
    return counts


@pytest.fixture(scope="module")
def past_the_wall(tmp_path_factory: pytest.TempPathFactory) -> tuple[Run, Run]:
    """The same drive past the wall, with noise, seed 0: with ``min_points = 1``, and the default."""
    folder = tmp_path_factory.mktemp("min_points")
    world, scenario = folder / "wall.toml", folder / "past_the_wall.toml"
    world.write_text(WORLD)
    scenario.write_text(SCENARIO)
    flags = ["--scenario", str(scenario), "--set", f"sim.world={world}"]
    flags += ["--set", f"lidar.noise={NOISE_M}", "--set", "lidar.seed=0"]
    every_point = up(folder / "min_points_1", *flags, *listen(), "--set", "collision_monitor.min_points=1")
    default = up(folder / "default", *flags, *listen())
    return every_point, default


@pytest.mark.slow
@pytest.mark.kinematic
def test_the_collision_monitor_with_lidar_noise_on_holds_on_no_stray_point(past_the_wall):
    every_point, default = past_the_wall
    for run in (every_point, default):
        assert run.returncode == ExitStatus.OK, run.output[-4000:]
        assert run.report["outcome"]["outcome"] == "completed", run.report["outcome"]
        assert run.on(KEYS.sim_bump) == [], "nothing touched"
    strays = hold_starts(every_point)
    assert len(strays) >= 3, "with min_points = 1, stray returns of the wall hold the robot"
    assert all(report.held_by.startswith("obstacle 'wall' in the stop zone") for report in strays)
    counts = stop_zone_counts(default)
    assert sum(1 for count in counts if count > 0) >= 5, ("strays in the stop zone, with the default too", counts)
    assert max(counts) < DEFAULT.min_points, counts
    assert hold_starts(default) == [], "with the default, no hold"
    assert all(report.held_by == "" for report in default.decoded(KEYS.motor_state, MotorStateReport))
    statuses = [json.loads(data)["collision_monitor"] for data in default.on(KEYS.status(Service.MOTOR))]
    assert statuses and all(status["min_points"] == DEFAULT.min_points for status in statuses)
    assert all(status["counters"]["holds"] == 0 for status in statuses)


def test_the_wall_is_outside_the_zones_and_a_noiseless_scan_of_it_has_no_point_inside():
    """The run's geometry without noise: the wall's returns all lie beyond the zones' side."""
    face_y = R + WALL_GAP_M
    angles = -math.pi + np.arange(RAYS) * 2 * math.pi / RAYS
    left = np.sin(angles) > 0.05
    ranges = face_y / np.sin(angles[left])
    x, y = ranges * np.cos(angles[left]), ranges * np.sin(angles[left])
    for length in (GEOMETRY.stop_distance, GEOMETRY.slow_distance):
        assert not in_swept_zone(x, y, 0.3, 0.0, R, length).any()
