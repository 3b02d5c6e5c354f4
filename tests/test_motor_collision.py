"""``invent motor``'s collision monitor in its own process over real zenoh, with hand-fed scans
(docs/protocol.md section 4.10): the hold, its release, the slow-down, ``min_points`` (one point
fewer does not hold), the stale-scan hold, bad scans, the order of a step's scan and wheel angles,
and the off switches (never a scan, disabled).

The torques are checked against a mirror MotorCore whose own CollisionMonitor is fed the same
scans, as tests/test_motor_service.py checks the control law.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from schemas.codec import ENCODING, encode
from schemas.keys import Keys, Service
from schemas.messages import LaserScan, MotorStateReport, Time
from services.config import load_config
from services.motor.core import MotorCore
from services.motor.monitor import CollisionMonitor
from tests.harness import Collector, InventProcess, free_port, open_peer, open_router, wait_alive, wait_until
from tests.test_motor_service import OVERRIDES, STEP_NS, MotorLink, moving, set_flags, wheels

ROBOT, DISABLED_ROBOT = "col1", "col2"
CONFIG = load_config(overrides={"robot.name": ROBOT, **OVERRIDES})
DISABLED = {**OVERRIDES, "collision_monitor.enabled": False}
RAYS = 360
MIN_POINTS = CONFIG.collision_monitor.min_points
FACE_RAYS = MIN_POINTS + 1
"""The rays a box's face ahead takes in these scans: more than the hold needs."""
BOX_HELD_BY = "obstacle 'box' in the stop zone, 0.31 m ahead at (0.76, 0.00) in base_link"


def flags(overrides: dict[str, Any]) -> list[str]:
    """``--set`` flags, booleans written as TOML has them."""
    return set_flags(
        {key: str(value).lower() if isinstance(value, bool) else value for key, value in overrides.items()}
    )


def ranges_ahead(distance: float | None, face: int = FACE_RAYS) -> list[float | None]:
    """A scan of :data:`RAYS` rays all round (ray 0 backwards) whose ``face`` rays about straight
    ahead see a box's face across the path ``distance`` ahead (the ray straight ahead first), and
    whose 20 rays about straight behind see a wall 2 m behind, outside every zone here: the points
    ahead are judged among more than ``min_points``."""
    ranges: list[float | None] = [None] * RAYS
    for offset in range(-10, 10):
        ranges[offset % RAYS] = 2.0 / math.cos(offset * 2 * math.pi / RAYS)
    for k in range(face):  # rays 0, +1, -1, +2, -2, ... from straight ahead
        offset = (k + 1) // 2 * (1 if k % 2 else -1)
        ranges[RAYS // 2 + offset] = None if distance is None else distance / math.cos(offset * 2 * math.pi / RAYS)
    return ranges


def laser_scan(stamp_ns: int, distance: float | None, face: int = FACE_RAYS, **fields: Any) -> LaserScan:
    return LaserScan(
        Time.from_nanoseconds(stamp_ns),
        angle_min=-math.pi,
        angle_increment=2 * math.pi / RAYS,
        range_min=0.12,
        range_max=3.5,
        ranges=ranges_ahead(distance, face),
        bodies=["box"],
        hits=[0] * RAYS,
        **fields,
    )


class ScanLink(MotorLink):
    """MotorLink with scans: the mirror core has a monitor of its own, fed the same scans."""

    def __init__(self, session: zenoh.Session, keys: Keys, config=CONFIG, monitored: bool = True) -> None:
        super().__init__(session, keys, config)
        self.monitored = monitored
        self.scan_publisher = session.declare_publisher(keys.sim_scan, encoding=zenoh.Encoding(ENCODING))
        self.states = Collector(session, keys.motor_state, MotorStateReport)
        self.last_scan_ns = 0

    def reset(self, vx: float, w: float) -> None:
        super().reset(vx, w)
        self._attach_monitor()

    def _attach_monitor(self) -> None:
        if self.monitored:
            config = self.config
            self.mirror.monitor = CollisionMonitor(
                config.robot, config.lidar, config.collision_monitor, config.input.stamp_horizon_ns
            )

    def collision(self) -> dict[str, Any]:
        return self.status()["collision_monitor"]

    def scan(
        self, distance: float | None, wait: bool = True, stamp_ns: int | None = None, face: int = FACE_RAYS
    ) -> None:
        """Publish a scan stamped at the last wheel sample's time (or ``stamp_ns``), a box's face of
        ``face`` rays ``distance`` ahead; ``wait``: until taken."""
        if stamp_ns is None:  # after the last scan, as the service takes them
            stamp_ns = max(self.time_ns, self.last_scan_ns + 1)
        self.last_scan_ns = stamp_ns
        message = laser_scan(stamp_ns, distance, face)
        seen = self.collision()["counters"]["scans"] if wait else 0
        self.scan_publisher.put(encode(message))
        if wait:
            wait_until(lambda: self.collision()["counters"]["scans"] > seen, what="the scan to be taken")
        if self.mirror.monitor is not None:
            self.mirror.monitor.take_scan(message, self.mirror.time_ns)

    def close(self) -> None:
        self.scan_publisher.undeclare()
        self.states.close()
        super().close()


@pytest.fixture(scope="module")
def links() -> Iterator[tuple[ScanLink, ScanLink]]:
    """A monitored motor and a disabled one, on one router."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    session = open_peer(endpoint)
    keys, disabled_keys = Keys(ROBOT), Keys(DISABLED_ROBOT)
    disabled_config = load_config(overrides={"robot.name": DISABLED_ROBOT, **DISABLED})
    monitored = ScanLink(session, keys)
    disabled = ScanLink(session, disabled_keys, disabled_config, monitored=False)
    try:
        with (
            InventProcess("motor", "--connect", endpoint, "--robot", ROBOT, *set_flags(OVERRIDES)) as motor,
            InventProcess("motor", "--connect", endpoint, "--robot", DISABLED_ROBOT, *flags(DISABLED)) as off,
        ):
            for link in (monitored, disabled):
                wait_alive(session, link.keys.alive(Service.MOTOR))
                link.wait_matched()
            wait_until(lambda: monitored.scan_publisher.matching_status.matching, what="the motor on sim/scan")
            yield monitored, disabled
            for process in (motor, off):
                code, _out, err = process.stop()
                assert code == 0, err
    finally:
        for link in (monitored, disabled):
            link.close()
        session.close()
        router.close()


@pytest.fixture
def link(links) -> ScanLink:
    return links[0]


def cycles(link: ScanLink, first: int, count: int) -> list[list[float]]:
    """``count`` cycles of moving wheels; each torque equal to the mirror's."""
    published = []
    for k in range(first, first + count):
        torques, expected = link.cycle(moving(k))
        assert torques == expected, k
        published.append(torques)
    return published


def last_state(link: ScanLink, held_by: str) -> MotorStateReport:
    """The motor/state sample that says ``held_by`` (earlier ones drained)."""

    def arrived() -> MotorStateReport | None:
        for report in link.states.drain():
            if report.held_by == held_by:
                return report
        return None

    return wait_until(arrived, what=f"motor/state held_by {held_by!r}")


def test_an_obstacle_in_the_stop_zone_holds_and_a_clear_scan_releases(link):
    link.reset(vx=0.5, w=0.0)
    link.scan(None)
    cycles(link, 1, 3)
    holds = link.collision()["counters"]["holds"]
    link.scan(0.76)
    cycles(link, 4, 3)
    status = link.status()
    assert status["state"] == "running", "a hold is no state of the Motor state machine"
    assert status["command"] == {"vx": 0.0, "w": 0.0} and status["target"] == {"vx": 0.5, "w": 0.0}
    collision = status["collision_monitor"]
    assert collision["held_by"] == BOX_HELD_BY and collision["zone"] == "stop"
    assert collision["nearest"]["body"] == "box" and collision["nearest"]["distance"] == pytest.approx(0.31)
    assert collision["counters"]["holds"] == holds + 1 and collision["counters"]["holds_by"]["obstacle"] >= 1
    report = last_state(link, BOX_HELD_BY)
    assert report.state == "running" and report.stopped_by == ""
    link.scan(None)
    cycles(link, 7, 2)
    assert link.status()["command"] == {"vx": 0.5, "w": 0.0}, "not latched: it drives on"
    assert last_state(link, "").state == "running"


def test_one_point_fewer_than_min_points_in_the_stop_zone_does_not_hold_and_min_points_do(link):
    assert MIN_POINTS > 1, "the default: a stray return does not hold"
    link.reset(vx=0.5, w=0.0)
    link.scan(None)
    holds = link.collision()["counters"]["holds"]
    link.scan(0.76, face=MIN_POINTS - 1)
    cycles(link, 1, 3)
    collision = link.collision()
    assert link.status()["command"] == {"vx": 0.5, "w": 0.0}, "not held, not slowed"
    assert collision["zone"] == "clear" and collision["held_by"] == "" and collision["counters"]["holds"] == holds
    assert collision["min_points"] == MIN_POINTS
    link.scan(0.76, face=MIN_POINTS)
    cycles(link, 4, 3)
    collision = link.collision()
    assert link.status()["command"] == {"vx": 0.0, "w": 0.0}
    assert collision["held_by"] == BOX_HELD_BY and collision["counters"]["holds"] == holds + 1


def test_backing_away_from_the_obstacle_is_not_held(link):
    link.reset(vx=0.5, w=0.0)
    link.scan(0.76)
    cycles(link, 1, 2)
    assert link.collision()["held_by"] == BOX_HELD_BY
    link.target(-0.3, 0.0)
    cycles(link, 3, 2)
    assert link.status()["command"] == {"vx": -0.3, "w": 0.0} and link.collision()["held_by"] == ""


def test_an_obstacle_in_the_slow_down_zone_slows_the_command(link):
    link.reset(vx=0.4, w=0.2)
    link.scan(None)
    slowdowns = link.collision()["counters"]["slowdowns"]
    link.scan(CONFIG.robot.radius_of_body_area + CONFIG.collision_monitor.margin + 0.6)
    cycles(link, 1, 3)
    factor = CONFIG.collision_monitor.slow_factor
    status = link.status()
    assert status["command"] == pytest.approx({"vx": 0.4 * factor, "w": 0.2 * factor})
    assert status["collision_monitor"]["zone"] == "slow" and status["collision_monitor"]["held_by"] == ""
    assert status["collision_monitor"]["counters"]["slowdowns"] == slowdowns + 1


def test_a_scan_older_than_the_timeout_holds_until_a_new_one(link):
    link.reset(vx=0.5, w=0.0)
    link.scan(None)
    timeout_ns = round(CONFIG.collision_monitor.scan_timeout * 1e9)
    stale = link.collision()["counters"]["holds_by"]["stale_scan"]
    torques, expected = link.cycle(moving(1), timeout_ns)
    assert torques == expected and link.status()["command"] == {"vx": 0.5, "w": 0.0}, "exactly the timeout: fresh"
    torques, expected = link.cycle(moving(2), 20 * STEP_NS)
    assert torques == expected and link.status()["command"] == {"vx": 0.0, "w": 0.0}
    held_by = "no scan for 0.52 s (collision_monitor.scan_timeout 0.5 s)"
    assert link.collision()["held_by"] == held_by and last_state(link, held_by).state == "running"
    assert link.collision()["counters"]["holds_by"]["stale_scan"] == stale + 1
    link.scan(None)
    link.target(0.5, 0.0)  # the drive's silence has timed the command out meanwhile (motor.command_timeout)
    cycles(link, 3, 2)
    assert link.status()["command"] == {"vx": 0.5, "w": 0.0} and link.collision()["held_by"] == ""


def test_a_steps_scan_applies_from_the_next_step_even_when_it_comes_before_its_wheel_angles(link):
    """A scan stamped with a step, published here just before that step's wheel angles (the
    simulator publishes it just after them): the motor may take it before it controls them, and
    still applies it from the next step's cycle on, every time, as the mirror core does."""
    link.reset(vx=0.5, w=0.0)
    for k in range(1, 9):
        link.scan(0.76 if k % 2 else None, wait=False, stamp_ns=link.time_ns + STEP_NS)
        torques, expected = link.cycle(moving(k))
        assert torques == expected, k
        held = k > 1 and (k - 1) % 2 == 1  # the scan of the step before saw the box
        assert link.mirror.command == ((0.0, 0.0) if held else (0.5, 0.0)), k


def test_bad_scans_are_dropped_counted_and_never_move_the_hold(link):
    link.reset(vx=0.5, w=0.0)
    link.scan(0.76)
    cycles(link, 1, 2)
    before = link.collision()
    key = link.keys.sim_scan
    good = laser_scan(link.time_ns + STEP_NS, None)
    bad_payloads = [
        b"{not json",
        encode(good).replace(b'"hits":[0,', b'"hits":['),  # one hit short of the ranges
        encode(laser_scan(link.last_scan_ns, None)),  # not after the last scan
        encode(laser_scan(link.time_ns + 5 * 10**9, None)),  # beyond the horizon
        encode(good).replace(b'"range_min":0.12', b'"range_min":9.0'),  # range_min above range_max
    ]
    for number, payload in enumerate(bad_payloads, start=1):
        link.scan_publisher.put(payload)
        wait_until(lambda n=number: link.bad_input_count(key) >= n, what=f"bad scan {number} counted")
    cycles(link, 3, 2)
    after = link.collision()
    assert after["counters"]["bad_scans"] == len(bad_payloads)
    assert after["counters"]["scans"] == before["counters"]["scans"] and after["held_by"] == BOX_HELD_BY
    assert link.status()["command"] == {"vx": 0.0, "w": 0.0}


def test_a_disabled_monitor_ignores_scans_and_controls_as_before(links):
    link = links[1]
    link.reset(vx=0.5, w=0.0)
    link.scan_publisher.put(encode(laser_scan(link.time_ns, 0.76)))
    cycles(link, 1, 3)
    status = link.status()
    assert status["collision_monitor"] == {"enabled": False} and status["command"] == {"vx": 0.5, "w": 0.0}
    assert key_not_subscribed(status, link.keys.sim_scan)


def key_not_subscribed(status: dict[str, Any], key: str) -> bool:
    return key not in status["inputs"]


def test_a_motor_that_never_had_a_scan_controls_as_before(endpoint, session):
    """Own process: a monitored motor with no scan is not monitored (the torques of a plain core)."""
    robot = "col3"
    keys = Keys(robot)
    config = load_config(overrides={"robot.name": robot, **OVERRIDES})
    link = ScanLink(session, keys, config, monitored=False)
    try:
        with InventProcess("motor", "--connect", endpoint, "--robot", robot, *set_flags(OVERRIDES)) as motor:
            wait_alive(session, keys.alive(Service.MOTOR))
            link.wait_matched()
            link.mirror = MotorCore(config.robot, config.motor)
            assert link.cycle(wheels(0.0, 0.0))[0] == [0.0, 0.0, 0.0]
            link.target(0.5, 0.0)
            cycles(link, 1, 5)
            collision = link.collision()
            assert collision["enabled"] is True and collision["monitoring"] is False and collision["held_by"] == ""
            assert link.status()["command"] == {"vx": 0.5, "w": 0.0}
            code, _out, err = motor.stop()
    finally:
        link.close()
    assert code == 0, err
