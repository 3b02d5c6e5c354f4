"""The simulated lidar and IMU: their arithmetic (pure), what they read in a real PyBullet world,
and what ``invent sim`` publishes over real zenoh (docs/protocol.md section 6.6)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadMessage, decode, encode
from schemas.keys import Keys
from schemas.messages import ImuSample, LaserScan, Time, TimedDoubleSeq
from services.body.geometry import robot_body
from services.config import ConfigError, ImuConfig, LidarConfig, RobotConfig, SimConfig
from services.runtime.inputs import contents
from sim_bridge.sensors import GRAVITY, Imu, Lidar, footprint_exit
from sim_bridge.simulator import Placement, Simulator
from sim_bridge.world import InitialPose, load_world, parse_world
from tests.harness import InventProcess, wait_until

KEYS = Keys()
REACH = robot_body(RobotConfig(), SimConfig()).reach
AHEAD = 180
"""The default lidar's ray straight ahead (360 rays from -π)."""
BOX_FACE_X = 0.9
"""The bump world's box: its near face, 0.9 m ahead of the default robot's axle centre."""


# --- pure ---


@given(st.floats(0.0, 0.44), st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi), st.floats(0.45, 1.0))
def test_a_ray_from_inside_the_footprint_leaves_it_on_its_edge(
    distance: float, bearing: float, heading: float, reach: float
):
    mount = (distance * math.cos(bearing), distance * math.sin(bearing))
    direction = (math.cos(heading), math.sin(heading))
    t = footprint_exit(mount, direction, reach)
    assert t > 0.0
    assert math.hypot(mount[0] + t * direction[0], mount[1] + t * direction[1]) == pytest.approx(reach, abs=1e-9)


def test_a_ray_that_misses_the_footprint_starts_at_the_lidar():
    assert footprint_exit((1.0, 0.0), (1.0, 0.0), 0.45) == 0.0, "pointing away from it"
    assert footprint_exit((1.0, 1.0), (0.0, 1.0), 0.45) == 0.0, "passing beside it"


def test_every_ray_starts_outside_the_robot_and_at_least_at_range_min():
    lidar = Lidar(LidarConfig(x=0.2, y=-0.1), REACH, stream=0)
    mount = np.array([0.2, -0.1, 0.1])
    starts = lidar.local_from
    assert np.all(np.hypot(starts[:, 0], starts[:, 1]) > REACH), (
        "beyond the footprint, by FOOTPRINT_CLEARANCE along the ray"
    )
    assert np.all(np.linalg.norm(starts - mount, axis=1) >= LidarConfig().range_min)
    assert np.allclose(np.linalg.norm(lidar.local_to - mount, axis=1), LidarConfig().range_max)


def test_a_lidar_whose_range_ends_inside_the_body_is_a_configuration_error():
    with pytest.raises(ConfigError, match="lidar.range_max"):
        Lidar(LidarConfig(range_min=0.0, range_max=0.3), REACH, stream=0)


def _hits(count: int, hit: dict[int, tuple[int, float]]) -> list:
    """A ray batch's results: ray -> (body, fraction) for the rays that hit; nothing for the others."""
    return [
        (*((hit[ray][0], -1, hit[ray][1]) if ray in hit else (-1, -1, 1.0)), (0, 0, 0), (0, 0, 0))
        for ray in range(count)
    ]


def test_a_scan_reads_each_hit_from_the_lidar_and_names_what_it_hit():
    config = LidarConfig(rays=4, range_max=3.0)
    lidar = Lidar(config, REACH, stream=0)
    scan = lidar.scan(Time(1, 0), _hits(4, {0: (7, 0.5), 2: (3, 0.0)}), {3: "box", 7: "rh1"})
    start = lidar.starts[0]
    assert scan.ranges == [pytest.approx(start + 0.5 * (3.0 - start)), None, pytest.approx(start), None]
    assert [scan.bodies[hit] if hit >= 0 else None for hit in scan.hits] == ["rh1", None, "box", None]
    assert (scan.angle_min, scan.angle_increment) == (-math.pi, math.pi / 2)
    assert decode(LaserScan, encode(scan)) == scan


def test_noise_is_the_same_for_the_same_seed_and_robot_and_differs_between_robots():
    config = LidarConfig(rays=8, noise=0.05, seed=7)
    hits = _hits(8, {ray: (1, 0.3) for ray in range(8)})

    def scans(stream: int) -> list[list[float | None]]:
        lidar = Lidar(config, REACH, stream)
        return [lidar.scan(Time(0, 0), hits, {1: "box"}).ranges for _ in range(3)]

    assert scans(0) == scans(0)
    assert scans(0) != scans(1)
    assert all(config.range_min <= reading <= config.range_max for scan in scans(0) for reading in scan if reading)


def test_an_imu_at_rest_reads_gravity_and_no_rotation():
    imu = Imu(ImuConfig(), stream=0)
    for k in range(3):
        identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        sample = imu.sample(Time(0, k * 10_000_000), (0.0, 0.0, 0.0, 1.0), identity, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        assert sample.angular_velocity == (0.0, 0.0, 0.0)
        assert sample.linear_acceleration == pytest.approx((0.0, 0.0, GRAVITY))
        assert sample.orientation_source == "simulator"


def test_an_imu_reads_its_bias_the_acceleration_in_its_own_axes_and_the_spin_at_its_mount():
    imu = Imu(ImuConfig(x=0.1, y=0.0, z=0.0, gyro_bias=(0.0, 0.0, 0.01), accel_bias=(0.2, 0.0, 0.0)), stream=0)
    turned = (0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # heading +90°, row-major
    quaternion = (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))
    imu.sample(Time(0, 0), quaternion, turned, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    sample = imu.sample(Time(0, 10_000_000), quaternion, turned, (0.0, 0.1, 0.0), (0.0, 0.0, 1.0))
    assert sample.angular_velocity == pytest.approx((0.0, 0.0, 1.01))
    # +0.1 m/s along world y in 10 ms is 10 m/s² along the base's x (it heads +y), plus the bias
    assert sample.linear_acceleration == pytest.approx((10.2, 0.0, GRAVITY))


# --- in a real PyBullet world ---


@pytest.fixture(scope="module")
def bump_world():
    sim = Simulator(RobotConfig(), SimConfig(), load_world("bump"), lidar=LidarConfig(), imu=ImuConfig())
    yield sim
    sim.close()


def test_the_range_straight_ahead_is_the_distance_to_the_box_face(bump_world):
    scan = bump_world.robots[0].scan(Time(0, 0))
    assert scan.ranges[AHEAD] == pytest.approx(BOX_FACE_X, abs=0.02)
    assert scan.bodies == ["box"]
    assert scan.angle_min + AHEAD * scan.angle_increment == pytest.approx(0.0)
    behind = scan.ranges[0]
    assert behind is None, "nothing behind the robot within range_max"


def test_a_lidar_never_sees_its_own_robot_wherever_it_sits():
    world = load_world("empty")
    for mount in (LidarConfig(), LidarConfig(x=0.3, y=0.2, z=0.0), LidarConfig(z=0.14, yaw=1.0)):
        sim = Simulator(RobotConfig(), SimConfig(), world, lidar=mount)
        try:
            scan = sim.robots[0].scan(Time(0, 0))
            assert scan.ranges == [None] * mount.rays and scan.bodies == [], mount
        finally:
            sim.close()


def test_a_lidar_sees_cylinders_and_the_other_robots_of_a_fleet_by_name():
    world = parse_world('[[cylinders]]\nname = "post"\nx = 0.0\ny = 1.5\nradius = 0.1\nheight = 0.5\n')
    lidar = LidarConfig()
    fleet = (
        Placement("rh0", RobotConfig(name="rh0"), InitialPose(), lidar),
        Placement("rh1", RobotConfig(name="rh1"), InitialPose(x=2.0, theta=math.pi), lidar),
    )
    sim = Simulator(RobotConfig(), SimConfig(), world, fleet=fleet)
    try:
        first, second = (robot.scan(Time(0, 0)) for robot in sim.robots)
        left = AHEAD + 90  # +90°: the post, 1.5 m to the left of rh0, its near side at 1.4 m
        assert first.bodies[first.hits[left]] == "post" and first.ranges[left] == pytest.approx(1.4, abs=0.02)
        assert first.bodies[first.hits[AHEAD]] == "rh1" and first.ranges[AHEAD] == pytest.approx(1.55, abs=0.02)
        assert second.bodies[second.hits[AHEAD]] == "rh0" and second.ranges[AHEAD] == pytest.approx(1.55, abs=0.02)
        assert "rh0" not in first.bodies and "rh1" not in second.bodies
        # the other robot is seen where it is now, not where it started
        sim.robots[1].set_torques([5.0, 5.0])
        for _ in range(500):
            sim.robots[1].set_torques([5.0, 5.0])
            sim.step()
        moved = sim.robots[0].scan(Time(0, 0)).ranges[AHEAD]
        assert moved is not None and moved < 1.5
    finally:
        sim.close()


def _drive(with_sensors: bool) -> tuple[list[float], list[float]]:
    sensors = {"lidar": LidarConfig(), "imu": ImuConfig()} if with_sensors else {}
    sim = Simulator(RobotConfig(), SimConfig(), load_world("bump"), **sensors)
    try:
        robot = sim.robots[0]
        for step in range(2000):
            if with_sensors and step % 100 == 0:
                robot.scan(Time(0, step))
                robot.imu_sample(Time(0, step))
            robot.set_torques([3.0 + (step % 7) * 0.1, 2.5])
            sim.step()
        return robot.body_pose(), robot.wheel_angles()
    finally:
        sim.close()


def test_sensing_leaves_the_physics_bit_for_bit_as_it_was():
    assert _drive(with_sensors=True) == _drive(with_sensors=False)


# --- invent sim over zenoh ---


def _sim_run(session, endpoint: str, duration_s: float, *flags: str) -> tuple[list[tuple[str, bytes]], str]:
    """``invent sim --duration`` with ``flags``: every ``sim/*`` sample it published, in arrival
    order (up to its last step's wheel angles), and its stderr."""
    arrivals: list[tuple[str, bytes]] = []
    subscriber = session.declare_subscriber(
        f"{KEYS.prefix}/sim/*", lambda sample: arrivals.append((str(sample.key_expr), contents(sample)[0]))
    )
    end = Time.from_nanoseconds(round(duration_s * 1e9))
    try:
        with InventProcess("sim", "--connect", endpoint, "--duration", str(duration_s), *flags) as sim:
            _out, err = sim.process.communicate(timeout=60)
            assert sim.process.returncode == 0, err
        wait_until(
            lambda: any(key == KEYS.sim_wheel_angles and decode(TimedDoubleSeq, p).tm == end for key, p in arrivals),
            10,
            "the last step",
        )
    finally:
        subscriber.undeclare()
    return arrivals, err


def test_invent_sim_publishes_scans_and_imu_samples_on_their_grids_between_their_steps_and_the_next_steps_wheel_angles(
    session, endpoint
):
    arrivals, _err = _sim_run(session, endpoint, 1, "--world", "bump")
    scans = [decode(LaserScan, payload) for key, payload in arrivals if key == KEYS.sim_scan]
    samples = [decode(ImuSample, payload) for key, payload in arrivals if key == KEYS.sim_imu]
    assert [scan.tm.to_nanoseconds() for scan in scans] == [k * 100_000_000 for k in range(11)], "10 Hz, 0 to 1 s"
    assert [sample.tm.to_nanoseconds() for sample in samples] == [k * 10_000_000 for k in range(101)], "100 Hz"
    assert all(scan.ranges[AHEAD] == pytest.approx(BOX_FACE_X, abs=0.02) for scan in scans), "standing still"
    assert all(sample.linear_acceleration == pytest.approx((0.0, 0.0, GRAVITY), abs=0.05) for sample in samples)
    angle_stamps = [
        (index, decode(TimedDoubleSeq, payload).tm)
        for index, (key, payload) in enumerate(arrivals)
        if key == KEYS.sim_wheel_angles
    ]
    for index, (key, payload) in enumerate(arrivals):
        if key in (KEYS.sim_scan, KEYS.sim_imu):
            stamp = decode(LaserScan if key == KEYS.sim_scan else ImuSample, payload).tm
            before = [tm for at, tm in angle_stamps if at < index]
            after = [tm for at, tm in angle_stamps if at > index]
            assert before[-1] == stamp, "after its step's wheel angles"
            assert not after or after[0].to_nanoseconds() == stamp.to_nanoseconds() + 1_000_000, (
                "before the next step's"
            )


def test_a_robot_without_sensors_publishes_none(session, endpoint):
    arrivals, err = _sim_run(session, endpoint, 0.3, "--set", "lidar.enabled=false", "--set", "imu.enabled=false")
    keys = {key for key, _payload in arrivals}
    assert KEYS.sim_scan not in keys and KEYS.sim_imu not in keys
    assert "scans 0" in err and "imu_samples 0" in err


def test_a_scan_that_is_not_one_cannot_be_decoded():
    with pytest.raises(BadMessage):
        decode(
            LaserScan,
            b'{"tm":{"sec":0,"nsec":0},"angle_min":0,"angle_increment":0.1,"range_min":0,"range_max":1,"ranges":[-1]}',
        )
