"""The collision monitor's pure core: the swept zones (services/motor/collision.py) against
hand-placed points and hypothesis properties, and the hold's state (services/motor/monitor.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import NO_HIT, LaserScan, Time
from services.config import RobotConfig
from services.config.sensors import CollisionMonitorConfig, LidarConfig
from services.motor.collision import MonitorGeometry, ScanPoints, Zone, in_swept_zone, judge
from services.motor.monitor import CollisionMonitor

NS = 1_000_000_000
GEOMETRY = MonitorGeometry(body_radius=0.45, margin=0.03, stop_distance=0.4, slow_distance=0.8)
R = GEOMETRY.footprint_radius


def points(*xy: tuple[float, float], body: str = "box") -> ScanPoints:
    x = np.array([p[0] for p in xy], dtype=np.float64)
    y = np.array([p[1] for p in xy], dtype=np.float64)
    return ScanPoints(x, y, np.zeros(len(xy), dtype=np.intp), [body], GEOMETRY.body_radius)


def zone(x: float, y: float, vx: float, w: float, length: float = 0.4, radius: float = R) -> bool:
    return bool(in_swept_zone(np.array([x]), np.array([y]), vx, w, radius, length)[0])


def scan(ranges: list[float | None], t: float = 0.0, hits: list[int] | None = None, bodies=("box",)) -> LaserScan:
    """A scan of len(ranges) rays all round, ray 0 pointing backwards (angle -π)."""
    count = len(ranges)
    return LaserScan(
        Time.from_nanoseconds(round(t * NS)),
        angle_min=-math.pi,
        angle_increment=2 * math.pi / count,
        range_min=0.12,
        range_max=3.5,
        ranges=ranges,
        bodies=list(bodies) if hits else [],
        hits=hits or [],
    )


def ahead(distance: float, rays: int = 360) -> list[float | None]:
    """A scan with one ray, straight ahead (angle 0, ray rays/2), seeing something at ``distance``."""
    ranges: list[float | None] = [None] * rays
    ranges[rays // 2] = distance
    return ranges


# --- the zones, hand-placed ------------------------------------------------------------------


def test_straight_zone_is_the_rectangle_ahead_and_its_caps():
    assert zone(R + 0.39, 0.0, 0.5, 0.0), "on the path, within the stop distance"
    assert not zone(R + 0.41, 0.0, 0.5, 0.0), "on the path, beyond it"
    assert zone(0.2, R - 0.01, 0.5, 0.0) and not zone(0.2, R + 0.01, 0.5, 0.0), "the rectangle's side"
    assert zone(0.4 + 0.3, 0.3, 0.5, 0.0) and not zone(0.4 + 0.4, 0.3, 0.5, 0.0), "the end cap, round"
    assert not zone(-R - 0.01, 0.0, 0.5, 0.0), "behind a forward motion"
    assert zone(-R - 0.39, 0.0, -0.5, 0.0) and not zone(R + 0.01, 0.0, -0.5, 0.0), "backwards sweeps backwards"


def test_turn_in_place_sweeps_the_footprint_alone():
    assert zone(R - 0.01, 0.0, 0.0, 1.0) and not zone(R + 0.01, 0.0, 0.0, 1.0)
    assert not zone(0.0, R + 0.01, 0.0, -1.0)


def test_an_arc_left_sweeps_to_the_left_and_not_the_right():
    # rho = 0.5 m to the left; a quarter turn is 0.785 m of travel, ending at (0.5, 0.5) heading +y
    quarter = math.pi / 2 * 0.5
    assert zone(0.5, 0.5 + R - 0.01, 0.5, 1.0, length=quarter), "the end cap"
    assert not zone(0.5, 0.5 + R + 0.01, 0.5, 1.0, length=quarter)
    assert zone(0.5 * math.sin(0.7), 0.5 - 0.5 * math.cos(0.7) - R + 0.01, 0.5, 1.0, length=quarter), "outer ring"
    assert not zone(0.2, -0.6, 0.5, 1.0, length=quarter), "right of the start, outside both"
    assert zone(0.2, -0.6, 0.5, -1.0, length=quarter), "the same point, turning right"


def test_a_full_circle_arc_covers_the_whole_annulus():
    rho = 1.0
    behind_the_centre = (0.0, 2.0 * rho)
    assert zone(*behind_the_centre, 1.0, 1.0, length=2 * math.pi * rho + 0.1)
    assert not zone(0.0, rho, 1.0, 1.0, length=100.0), "the centre of a ring wider than the footprint"


def test_judge_stop_slow_clear_and_the_obstacle_named():
    verdict = judge(points((R + 0.3, 0.02), (R + 0.35, -0.1)), 0.3, 0.0, GEOMETRY)
    assert verdict.zone is Zone.STOP and verdict.obstacle is not None
    assert verdict.obstacle.x == pytest.approx(R + 0.3) and verdict.obstacle.body == "box"
    assert verdict.describe(0.3) == "obstacle 'box' in the stop zone, 0.33 m ahead at (0.78, 0.02) in base_link"
    assert judge(points((R + 0.6, 0.0)), 0.3, 0.0, GEOMETRY).zone is Zone.SLOW
    assert judge(points((R + 0.9, 0.0)), 0.3, 0.0, GEOMETRY).zone is Zone.CLEAR
    assert judge(points((R + 0.3, 0.0)), 0.0, 0.0, GEOMETRY).zone is Zone.CLEAR, "no motion, no zone"
    no_slow = MonitorGeometry(0.45, 0.03, 0.4, 0.0)
    assert judge(points((R + 0.6, 0.0)), 0.3, 0.0, no_slow).zone is Zone.CLEAR


def test_scan_points_through_the_lidar_mount_and_the_bodies_hit():
    mounted = MonitorGeometry(0.45, 0.03, 0.4, 0.8, lidar_x=0.1, lidar_y=0.05, lidar_yaw=math.pi / 2)
    message = scan([None, 1.0, 0.05, 2.0], hits=[NO_HIT, 0, NO_HIT, 1], bodies=("box", "rh1"))
    # rays at -π, -π/2, 0, π/2 about the lidar, which faces +y: base angles -π/2, 0, π/2, π
    cloud = ScanPoints.from_scan(message, mounted)
    assert len(cloud) == 2, "None is nothing, 0.05 < range_min is no measurement"
    first, second = cloud.obstacle(0), cloud.obstacle(1)
    assert (first.x, first.y, first.body) == pytest.approx((1.1, 0.05, "box"))
    assert (second.x, second.y, second.body) == pytest.approx((-1.9, 0.05, "rh1"))
    assert cloud.nearest() == first and first.clearance == pytest.approx(math.hypot(1.1, 0.05) - 0.45)


def test_all_ranges_none_is_clear_and_has_no_nearest():
    cloud = ScanPoints.from_scan(scan([None] * 90), GEOMETRY)
    assert len(cloud) == 0 and cloud.nearest() is None
    assert judge(cloud, 1.0, 0.5, GEOMETRY).zone is Zone.CLEAR


# --- properties --------------------------------------------------------------------------------

speeds = st.floats(0.01, 2.0)
turns = st.floats(-3.0, 3.0)
coordinates = st.floats(-3.0, 3.0)


@given(speeds, turns, st.floats(0.0, 0.39))
def test_a_point_on_the_path_within_the_stop_distance_holds(vx, w, travel):
    """The point the footprint's front reaches after ``travel`` along the arc holds, forward and back."""
    for sign in (1.0, -1.0):
        v = sign * vx
        if abs(w) * travel / vx < 1e-6:
            x, y = sign * (travel + R * 0.99), 0.0
        else:
            rho = v / w
            phi = w * travel / v * sign  # the heading after travel (signed as w)
            cx, cy = rho * math.sin(phi), rho - rho * math.cos(phi)  # the centre there
            x, y = cx + sign * 0.99 * R * math.cos(phi), cy + sign * 0.99 * R * math.sin(phi)
        assert judge(points((x, y)), v, w, GEOMETRY).zone is Zone.STOP, (v, w, travel, x, y)


@given(speeds, st.floats(-0.3, 0.3), st.floats(0.01, 3.0), coordinates)
def test_a_point_behind_never_holds_a_forward_motion(vx, w, behind, y):
    """Behind the footprint (x < -R), gently curving forward motion never reaches back there."""
    assume(abs(w) * 0.8 / vx < 1.0)  # turning less than a radian over the zones
    assert judge(points((-R - behind, y)), vx, w, GEOMETRY).zone is Zone.CLEAR


@given(speeds, turns, coordinates, coordinates, st.floats(0.1, 10.0))
def test_scaling_every_length_keeps_the_verdict(vx, w, x, y, k):
    base = in_swept_zone(np.array([x]), np.array([y]), vx, w, R, 0.4)[0]
    scaled = in_swept_zone(np.array([k * x]), np.array([k * y]), k * vx, w, k * R, k * 0.4)[0]
    # a point within a hair of the boundary may fall either way
    near_edge = bool(in_swept_zone(np.array([x]), np.array([y]), vx, w, R * 1.0001, 0.4001)[0]) != bool(
        in_swept_zone(np.array([x]), np.array([y]), vx, w, R * 0.9999, 0.3999)[0]
    )
    assert base == scaled or near_edge


@given(speeds, turns, coordinates, coordinates, st.floats(0.1, 10.0))
def test_the_zone_depends_on_the_path_not_the_speed_and_mirrors_with_the_turn(vx, w, x, y, c):
    def inside(vx: float, w: float, y: float) -> bool:
        return bool(in_swept_zone(np.array([x]), np.array([y]), vx, w, R, 0.4)[0])

    assume(abs(w) * 0.4 / vx > 1e-5 or w == 0.0)  # not at the straight-line switch
    assert inside(vx, w, y) == inside(c * vx, c * w, y)
    assert inside(vx, w, y) == inside(vx, -w, -y)


@given(speeds, turns, coordinates, coordinates)
def test_the_stop_zone_lies_within_the_slow_down_zone(vx, w, x, y):
    stop = in_swept_zone(np.array([x]), np.array([y]), vx, w, R, 0.4)[0]
    slow = in_swept_zone(np.array([x]), np.array([y]), vx, w, R, 0.8)[0]
    assert slow or not stop


# --- the monitor's hold ------------------------------------------------------------------------


def monitor(**settings: object) -> CollisionMonitor:
    """A monitor that acts on any point (``min_points`` 1 unless given): these scans have one ray
    (tests/test_collision_min_points.py tests the default)."""
    return CollisionMonitor(RobotConfig(), LidarConfig(), CollisionMonitorConfig(**{"min_points": 1, **settings}), NS)


def test_a_monitor_without_a_scan_never_holds():
    watcher = monitor()
    assert watcher.factor(0, 1.0, 0.0) == 1.0 and watcher.factor(10 * NS, 1.0, 0.0) == 1.0
    assert watcher.held_by == "" and watcher.holds == 0


def test_a_hold_starts_with_an_obstacle_in_the_stop_zone_and_ends_with_a_clear_scan():
    watcher = monitor()
    watcher.take_scan(scan(ahead(0.76), hits=[0] * 360), 0)
    assert watcher.factor(1_000_000, 0.3, 0.0) == 0.0
    assert watcher.held_by == "obstacle 'box' in the stop zone, 0.31 m ahead at (0.76, 0.00) in base_link"
    assert watcher.factor(2_000_000, 0.3, 0.0) == 0.0 and watcher.holds == 1, "one hold, not one per cycle"
    assert watcher.factor(3_000_000, -0.3, 0.0) == 1.0 and watcher.held_by == "", "backing away is clear"
    assert watcher.factor(4_000_000, 0.3, 0.0) == 0.0 and watcher.holds == 2
    watcher.take_scan(scan(ahead(1.1), t=0.1), 100_000_000)
    assert watcher.factor(101_000_000, 0.3, 0.0) == 0.5 and watcher.held_by == "" and watcher.slowdowns == 1
    watcher.take_scan(scan(ahead(None), t=0.2), 200_000_000)  # type: ignore[arg-type]
    assert watcher.factor(201_000_000, 0.3, 0.0) == 1.0 and watcher.holds_by == {"obstacle": 2, "stale_scan": 0}


def test_a_stale_scan_holds_until_the_next_scan():
    watcher = monitor(scan_timeout=0.5)
    watcher.take_scan(scan(ahead(None)), 0)  # type: ignore[arg-type]
    assert watcher.factor(500_000_000, 0.3, 0.0) == 1.0, "exactly the timeout is still fresh"
    assert watcher.factor(520_000_000, 0.3, 0.0) == 0.0
    assert watcher.held_by == "no scan for 0.52 s (collision_monitor.scan_timeout 0.5 s)"
    assert watcher.factor(530_000_000, 0.0, 0.0) == 0.0 and watcher.holds_by["stale_scan"] == 1
    watcher.take_scan(scan(ahead(None), t=0.55), 540_000_000)  # type: ignore[arg-type]
    assert watcher.factor(551_000_000, 0.3, 0.0) == 1.0 and watcher.held_by == ""


def test_bad_scans_raise_and_change_nothing():
    watcher = monitor()
    watcher.take_scan(scan(ahead(0.76), t=1.0), NS)
    watcher.factor(NS + 1, 0.3, 0.0)
    before = (watcher.scan_ns, watcher.scans, watcher.held_by, watcher.nearest)
    for bad, reason in (
        (scan(ahead(None), t=1.0), "dt = 0 s <= 0"),  # type: ignore[arg-type]
        (scan(ahead(None), t=0.9), "dt"),  # type: ignore[arg-type]
        (scan(ahead(None), t=2.5), "ahead"),  # type: ignore[arg-type]
    ):
        with pytest.raises(BadInput, match=reason):
            watcher.take_scan(bad, NS)
    assert (watcher.scan_ns, watcher.scans, watcher.held_by, watcher.nearest) == before
    assert watcher.factor(NS + 1_000_000, 0.3, 0.0) == 0.0


def test_forget_is_a_new_time_base_with_no_scan_and_no_hold():
    watcher = monitor()
    watcher.take_scan(scan(ahead(0.76), t=5.0), 5 * NS)
    assert watcher.factor(5 * NS, 0.3, 0.0) == 1.0, "a scan applies from the first cycle after it"
    assert watcher.factor(5 * NS + 1, 0.3, 0.0) == 0.0
    watcher.forget()
    assert watcher.held_by == "" and watcher.factor(0, 0.3, 0.0) == 1.0
    watcher.take_scan(scan(ahead(0.76), t=0.0), None)
    assert watcher.factor(1_000_000, 0.3, 0.0) == 0.0


# --- in MotorCore --------------------------------------------------------------------------------


def test_a_held_core_brakes_through_the_acceleration_limit_and_stays_running():
    from services.config import MotorConfig
    from services.motor.core import MotorCore, MotorState

    motor = MotorConfig()
    plain, held = MotorCore(RobotConfig(), motor), MotorCore(RobotConfig(), motor)
    held.monitor = monitor()
    for motor_core in (plain, held):
        motor_core.set_target(0.5, 0.0)
        motor_core.step(0, [0.0, 0.0])
    for k in range(1, 51):  # 0.5 s at 10 ms: both ramp up at max_ax, with no scan alike
        assert plain.step(k * 10_000_000, [0.0, 0.0]) == held.step(k * 10_000_000, [0.0, 0.0])
    assert held.command == pytest.approx((0.5, 0.0))
    held.set_target(0.5, 0.0, held.time_ns)  # a fresh command (motor.command_timeout)
    held.monitor.take_scan(scan(ahead(0.76), t=0.5), held.time_ns)
    held.step(510_000_000, [0.0, 0.0])
    assert held.command == pytest.approx((0.5 - motor.max_ax * 0.01, 0.0)), "through the acceleration limit"
    assert held.state is MotorState.RUNNING and held.monitor.held_by.startswith("an obstacle in the stop zone")
