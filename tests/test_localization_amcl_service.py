"""``invent localization`` with ``localization.mode = amcl`` (and ``none``) in its own process over real
zenoh, fed synthetic wheel angles and scans of a square room 4 m a side, the robot standing at the
origin: the initial pose first, then estimates with their covariance at the rate; the particles; the
initial pose and the global localization at any time; bad input refused, counted, and harmless."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import LaserScan, Time, TimedDoubleSeq, TimedPosition
from schemas.navigation import InitialPose, LocalizationReply, ParticleCloud
from services.config import LidarConfig
from services.config.amcl import AmclConfig
from services.navigation.grid import FREE, OCCUPIED, Grid, GridGeometry
from services.navigation.map_file import write_map
from tests.harness import Collector, InventProcess, call, run_invent, status_reply, wait_alive, wait_until

KEYS = Keys()
LIDAR = LidarConfig()
HALF_ROOM = 2.0
"""The room's inner faces at x, y = ±2 m."""
STEP_NS = 10_000_000
SCAN_EVERY = 10
"""A scan every 10 steps: the lidar's 10 Hz."""


def room_map(folder: Path) -> Path:
    geometry = GridGeometry(0.05, 100, 100, -2.5, -2.5)
    cells = np.full(geometry.shape, FREE, dtype=np.int8)
    centres = -2.5 + 0.05 * (np.arange(100) + 0.5)
    outside = np.abs(centres) > HALF_ROOM
    cells[outside, :] = OCCUPIED
    cells[:, outside] = OCCUPIED
    path = folder / "room.yaml"
    write_map(Grid(geometry, cells), path)
    return path


def scan_at_origin(stamp_ns: int, rays: int = LIDAR.rays) -> LaserScan:
    """What the lidar at the origin, facing +x, sees of the room's walls."""
    ranges: list[float | None] = []
    for index in range(rays):
        angle = LIDAR.angle_min + index * LIDAR.span / rays
        cos, sin = math.cos(angle), math.sin(angle)
        distance = min(HALF_ROOM / abs(value) for value in (cos, sin) if abs(value) > 1e-12)
        ranges.append(distance if distance <= LIDAR.range_max else None)
    return LaserScan(
        tm=Time.from_nanoseconds(stamp_ns),
        angle_min=LIDAR.angle_min,
        angle_increment=LIDAR.span / rays,
        range_min=LIDAR.range_min,
        range_max=LIDAR.range_max,
        ranges=ranges,
    )


class Feed:
    """The simulator's and the motor's side: a scan on the lidar's grid, then the step's wheel angles."""

    def __init__(self, session: zenoh.Session) -> None:
        self.wheels = session.declare_publisher(KEYS.motor_wheel_angles)
        self.scans = session.declare_publisher(KEYS.sim_scan)
        self.step = 0

    def run(self, steps: int) -> None:
        for _ in range(steps):
            stamp_ns = self.step * STEP_NS
            if self.step % SCAN_EVERY == 0:
                self.scans.put(encode(scan_at_origin(stamp_ns)))
            self.wheels.put(encode(TimedDoubleSeq(tm=Time.from_nanoseconds(stamp_ns), data=[0.0, 0.0])))
            self.step += 1


def localization(endpoint: str, map_file: Path, mode: str = "amcl") -> InventProcess:
    return InventProcess(
        "localization", "--connect", endpoint, "--log-level", "warning",
        "--set", f"localization.mode={mode}", "--set", f"navigation.map={map_file}",
        "--set", "localization.rate=2", "--set", "localization.particles_rate=2", "--set", "localization.seed=1",
        "--initial", "0.1", "-0.1", "0.05",
    )  # fmt: skip


def status(session: zenoh.Session) -> dict:
    return status_reply(session, KEYS, Service.LOCALIZATION)


def ask(session: zenoh.Session, key: str, payload: bytes) -> LocalizationReply:
    ok, reply = call(session, key, payload)
    assert ok, reply
    return msgspec.convert(reply, LocalizationReply)


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    return room_map(tmp_path)


def started(session: zenoh.Session, feed: Feed, fixes: Collector) -> TimedPosition:
    """Feed steps until the first fix comes (the schedule starts once the fixes have a subscriber)."""
    wait_until(lambda: feed.wheels.matching_status.matching, 10, "the wheel angles' subscriber")
    for _ in range(100):
        feed.run(SCAN_EVERY)
        try:
            return fixes.get(timeout=0.3)
        except AssertionError:
            continue
    raise AssertionError("no first fix")


def test_the_initial_pose_then_estimates_with_their_covariance_and_the_particles(endpoint, session, map_file):
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    particles = Collector(session, KEYS.localization_particles, ParticleCloud)
    with localization(endpoint, map_file):
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        feed = Feed(session)
        first = started(session, feed, fixes)
        assert math.hypot(first.x - 0.1, first.y + 0.1) < 0.25, "near the initial pose the filter was seeded around"
        assert len(first.error) == 6 and first.error[0] > 0.0, "its covariance"
        feed.run(300)  # 3 simulated seconds, standing at the origin
        estimates = [fixes.get(timeout=5.0) for _ in range(5)]
        assert all(len(estimate.error) == 6 for estimate in estimates)
        last = estimates[-1]
        assert math.hypot(last.x, last.y) < 0.05 and abs(last.theta) < 0.05, "it found the origin"
        cloud = particles.get(timeout=5.0)
        assert len(cloud.x) >= AmclConfig().min_particles
        assert math.isclose(sum(cloud.weight), 1.0, rel_tol=1e-6)
        report = wait_until(lambda: (r := status(session))["counters"]["scans"] >= 30 and r, 10, "every scan taken")
        assert report["mode"] == "amcl" and report["filter"]["updates"] >= 1 and report["internal_errors"] == 0


def test_an_initial_pose_takes_at_any_time_and_bad_ones_are_refused_and_counted(endpoint, session, map_file):
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with localization(endpoint, map_file):
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        feed = Feed(session)
        started(session, feed, fixes)
        key = KEYS.localization_initial_pose
        off = ask(session, key, msgspec.json.encode(InitialPose(x=30.0, y=0.0, theta=0.0)))
        assert not off.accepted and "off the map" in off.reason
        not_finite = ask(session, key, b'{"x": 0.0, "y": NaN, "theta": 0.0}')
        assert not not_finite.accepted and "not an InitialPose" in not_finite.reason
        bad_covariance = ask(
            session, key, msgspec.json.encode(InitialPose(x=0.0, y=0.0, theta=0.0, covariance=[1, 0, 0, -1, 0, 1]))
        )
        assert not bad_covariance.accepted and "covariance" in bad_covariance.reason
        taken = ask(session, key, msgspec.json.encode(InitialPose(x=0.5, y=0.5, theta=0.3)))
        assert taken.accepted and taken.reason == ""
        assert ask(session, KEYS.localization_global_localization, b"{}").accepted
        feed.scans.put(encode(scan_at_origin(feed.step * STEP_NS, rays=LIDAR.rays - 1)))
        feed.run(2 * SCAN_EVERY)
        report = wait_until(
            lambda: (r := status(session))["bad_input"]["total"] >= 4 and r, 10, "the bad inputs counted"
        )
        assert report["counters"]["initial_poses"] == 1 and report["counters"]["global_localizations"] == 1
        by_key = report["bad_input"]["by_key"]
        assert by_key[key]["count"] == 3 and by_key[KEYS.sim_scan]["count"] == 1, by_key
        assert report["internal_errors"] == 0


def test_none_publishes_the_initial_pose_once_and_no_more(endpoint, session, map_file):
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with localization(endpoint, map_file, mode="none"):
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        feed = Feed(session)
        first = started(session, feed, fixes)
        assert (first.x, first.y, first.theta, first.error) == (0.1, -0.1, 0.05, [])
        feed.run(300)
        assert fixes.drain() == [], "no fix after the initial pose"
        report = status(session)
        assert report["mode"] == "none" and report["initial_published_at"] is not None


def test_an_initial_pose_off_the_map_is_a_configuration_error(map_file):
    result = run_invent(
        "localization", "--set", "localization.mode=amcl", "--set", f"navigation.map={map_file}",
        "--initial", "30", "0", "0",
    )  # fmt: skip
    assert result.returncode == 2 and "localization.initial_x" in result.stderr and "off the map" in result.stderr
