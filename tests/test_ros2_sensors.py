"""The robot's lidar and IMU in ROS 2 (services/ros2/sensors.py): ``scan`` and ``imu`` built from
``sim/scan`` and ``sim/imu``, their type hashes equal to the ones ROS ships (tests/data/ros2_interfaces,
copied from ROS's ``sensor_msgs`` wheel), their sensor QoS, their frames in the URDF and on
``tf_static``, bad input refused, and both in a bag exported from a recording.

Then ``invent ros2 --fleet`` fed by hand on a real zenoh network (two robots, each in its namespace):
a ROS-side client (tests/ros_client.py) sees the topics in the graph with their QoS, decodes each
robot's ``scan`` and ``imu``, finds the sensor frames in each robot's ``tf_static``, a malformed,
non-finite or out-of-order sample counted and dropped with the bridge living on, and ``invent
record --ros2`` recording both into a bag. One bridge process serves those tests.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from schemas.codec import BadInput, encode
from schemas.keys import Keys, Service
from schemas.messages import ImuSample, LaserScan, Time, TimedDoubleSeq
from services.config import load_config
from services.recording.mcap_files import McapWriter
from services.recording.rosbag import ExportedRobot, export_run
from services.ros2 import interfaces, sensors, wire
from services.ros2.graph import bridge_graph
from services.ros2.outputs import RosOutputs
from services.ros2.urdf import robot_urdf
from tests import ros_client
from tests.harness import InventProcess, call, peer_session, running_router, wait_until

SHIPPED = Path(__file__).parent / "data" / "ros2_interfaces"
SENSOR_QOS = "2::,5:,:,:,,"
"""rclcpp's SensorDataQoS in a token: best effort, volatile (the default), keep-last 5."""
MS = 1_000_000
TYPES = {"scan": interfaces.LASER_SCAN, "imu": interfaces.IMU}


def _shipped_hash(name: str) -> str:
    """The RIHS01 hash ROS computed for ``name``, from its type description (``type_hashes``)."""
    package, _msg, type_name = name.split("/")
    description = json.loads((SHIPPED / package / "msg" / f"{type_name}.json").read_text())
    (entry,) = [e for e in description["type_hashes"] if e["type_name"] == name]
    return entry["hash_string"]


@pytest.mark.parametrize("name", [interfaces.LASER_SCAN, interfaces.IMU])
def test_the_sensor_types_hashes_are_the_ones_ros_ships(name):
    shipped = _shipped_hash(name)
    assert shipped.startswith("RIHS01_") and len(shipped) == 7 + 64
    assert interfaces.interface(name).type_hash == shipped
    for store in (Stores.ROS2_JAZZY, Stores.ROS2_KILTED):
        assert get_typestore(store).hash_rihs01(name) == shipped, store
    bridge = bridge_graph(load_config(overrides={"ros2.namespace": "rh1"}), environ={})
    topic = next(topic for topic, entity in bridge.publications.items() if entity.interface == name)
    assert bridge.key(bridge.publications[topic]).endswith(f"/{shipped}")


def test_scan_and_imu_are_offered_with_rclcpps_sensor_data_qos():
    assert wire.SENSOR_DATA.token_chunk() == SENSOR_QOS
    publications = bridge_graph(load_config(), environ={}).publications
    assert {topic: publications[topic].qos for topic in TYPES} == {"scan": wire.SENSOR_DATA, "imu": wire.SENSOR_DATA}


def _scan(stamp_ns: int, ranges: list[float | None], **fields: Any) -> LaserScan:
    values = {"angle_min": -math.pi, "angle_increment": math.tau / len(ranges or [0]), "range_min": 0.12}
    return LaserScan(tm=Time.from_nanoseconds(stamp_ns), ranges=ranges, **{"range_max": 3.5, **values, **fields})


def _imu(stamp_ns: int, source: str = "simulator", gyro_z: float = 0.5) -> ImuSample:
    return ImuSample(
        tm=Time.from_nanoseconds(stamp_ns),
        orientation=(0.0, 0.0, math.sin(0.2), math.cos(0.2)),
        orientation_source=source,  # type: ignore[arg-type]
        angular_velocity=(0.01, -0.02, gyro_z),
        linear_acceleration=(0.3, 0.0, 9.81),
    )


def _outputs(**overrides: Any) -> RosOutputs:
    config = load_config(overrides=overrides)
    return RosOutputs(config, bridge_graph(config, environ={}))


ranges = st.lists(st.one_of(st.none(), st.floats(0.0, 1e6)), min_size=1, max_size=720)


@given(ranges)
def test_a_scan_is_a_laser_scan_with_inf_for_nothing_in_range_float32_ranges_and_no_intensities(values):
    outputs = _outputs(**{"lidar.rate": 20.0})
    (out,) = outputs.take_scan(_scan(1_500 * MS, values))
    decoded = ros_client.TYPESTORE.deserialize_cdr(interfaces.serialize(out.message), interfaces.LASER_SCAN)
    expected = np.array([math.inf if value is None else value for value in values], dtype=np.float32)
    assert decoded.ranges.dtype == np.float32 and np.array_equal(decoded.ranges, expected)
    assert len(decoded.intensities) == 0
    assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec, decoded.header.frame_id) == (
        1,
        500 * MS,
        "base_scan",
    )
    assert decoded.angle_min == pytest.approx(-math.pi)
    assert decoded.angle_max == pytest.approx(-math.pi + (len(values) - 1) * math.tau / len(values), abs=1e-5)
    assert (decoded.time_increment, decoded.scan_time) == (0.0, pytest.approx(1 / 20.0))
    assert (decoded.range_min, decoded.range_max) == (pytest.approx(0.12), 3.5)
    assert out.stamp_ns == 1_500 * MS


@pytest.mark.parametrize("source", ["none", "simulator", "estimate"])
def test_an_imu_sample_is_an_imu_with_covariances_from_the_noise_and_rep_145s_no_orientation(source):
    outputs = _outputs(**{"imu.gyro_noise": 0.01, "imu.accel_noise": 0.2})
    (out,) = outputs.take_imu(_imu(20 * MS, source))
    imu = ros_client.TYPESTORE.deserialize_cdr(interfaces.serialize(out.message), interfaces.IMU)
    assert imu.header.frame_id == "imu_link" and imu.header.stamp.nanosec == 20 * MS
    assert (imu.angular_velocity.z, imu.linear_acceleration.z) == (0.5, 9.81)
    assert imu.orientation.z == pytest.approx(math.sin(0.2))
    assert np.allclose(imu.angular_velocity_covariance, np.diag([1e-4] * 3).reshape(9))
    assert np.allclose(imu.linear_acceleration_covariance, np.diag([0.04] * 3).reshape(9))
    if source == "none":
        assert imu.orientation_covariance[0] == -1.0 and not imu.orientation_covariance[1:].any()
    else:
        assert np.array_equal(imu.orientation_covariance, np.diag([sensors.ORIENTATION_VARIANCE] * 3).reshape(9))


@pytest.mark.parametrize(
    ("feed", "reason"),
    [
        ([_scan(2 * MS, [1.0]), _scan(1 * MS, [1.0])], "not after the last scan's"),
        ([_scan(2 * MS, [1.0]), _scan(2 * MS, [1.0])], "not after the last scan's"),
        ([_imu(5 * MS), _imu(4 * MS)], "not after the last imu's"),
        ([_scan(1 * MS, [])], "without rays"),
        ([_scan(1 * MS, [1e39])], "float32"),
        ([_scan(1 * MS, [1.0], angle_increment=1e39)], "float32"),
        ([_scan((2**31) * 1_000 * MS, [1.0])], "int32"),
    ],
)
def test_a_sensor_sample_out_of_order_or_that_ros_cannot_hold_is_bad_input(feed, reason):
    outputs = _outputs()
    *good, bad = feed
    take = outputs.take_scan if isinstance(bad, LaserScan) else outputs.take_imu
    for message in good:
        assert take(message)
    with pytest.raises(BadInput, match=reason):
        take(bad)


def test_a_sensor_sample_far_ahead_of_the_clock_is_bad_input_and_a_new_simulator_starts_the_stamps_again():
    outputs = _outputs()
    outputs.take_wheels(TimedDoubleSeq(tm=Time.from_nanoseconds(5_000 * MS), data=[0.0, 0.0]))
    with pytest.raises(BadInput, match="stamp_horizon ahead of the clock"):
        outputs.take_imu(_imu(7_000 * MS))
    assert outputs.take_imu(_imu(5_010 * MS)), "the next good sample is taken"
    outputs.clock.restart.simulator_appeared()
    assert outputs.take_wheels(TimedDoubleSeq(tm=Time.from_nanoseconds(0), data=[0.0, 0.0])).restarted
    assert outputs.take_imu(_imu(10 * MS)), "a new simulator's stamps start again"


@pytest.mark.parametrize("layout", ["namespaced", "prefixed"])
def test_the_sensor_frames_are_fixed_joints_of_the_urdf_and_on_tf_static_at_their_mounts(layout):
    outputs = _outputs(
        **{
            "ros2.namespace": "rh1",
            "ros2.tf": layout,
            "lidar.x": 0.05,
            "lidar.z": 0.12,
            "lidar.yaw": math.pi / 2,
            "imu.x": -0.03,
            "imu.y": 0.01,
        }
    )
    prefix = "rh1/" if layout == "prefixed" else ""
    static, description = outputs.latched()
    by_child = {t.child_frame_id: t for t in static.message.transforms}
    scan, imu = by_child[prefix + "base_scan"], by_child[prefix + "imu_link"]
    assert scan.header.frame_id == imu.header.frame_id == prefix + "base_link"
    t = scan.transform
    assert (t.translation.x, t.translation.y, t.translation.z) == (0.05, 0.0, 0.12)
    assert (t.rotation.z, t.rotation.w) == (pytest.approx(math.sin(math.pi / 4)), pytest.approx(math.cos(math.pi / 4)))
    t = imu.transform
    assert (t.translation.x, t.translation.y, t.translation.z, t.rotation.w) == (-0.03, 0.01, 0.05, 1.0)
    root = ElementTree.fromstring(description.message.data)
    joints = {j.find("child").get("link"): j for j in root.iter("joint")}
    for link, xyz, rpy in (
        ("base_scan", "0.05 0 0.12", f"0 0 {math.pi / 2:.9g}"),
        ("imu_link", "-0.03 0.01 0.05", "0 0 0"),
    ):
        assert root.find(f"link[@name='{link}']") is not None, "unprefixed in the URDF, as the other links"
        joint = joints[link]
        assert (joint.get("type"), joint.find("parent").get("link")) == ("fixed", "base_link")
        assert (joint.find("origin").get("xyz"), joint.find("origin").get("rpy")) == (xyz, rpy)
    assert (outputs.take_scan(_scan(MS, [1.0]))[0].message.header.frame_id) == prefix + "base_scan"


def test_a_robot_without_the_sensors_publishes_neither_topic_nor_frame():
    outputs = _outputs(**{"lidar.enabled": False, "imu.enabled": False})
    assert not {"scan", "imu"} & set(outputs.topics)
    assert outputs.take_scan(_scan(MS, [1.0])) == [] and outputs.take_imu(_imu(MS)) == []
    static, description = outputs.latched()
    assert {t.child_frame_id for t in static.message.transforms} == {"front_caster", "rear_caster"}
    assert "base_scan" not in description.message.data
    body = outputs.body
    assert robot_urdf("rh0", "base_link", body) == description.message.data


def test_export_ros2_writes_the_recordings_scans_and_imu_samples_into_the_bag(tmp_path):
    """A recording holding ``sim/clock``, ``sim/scan`` and ``sim/imu`` (written by hand, as ``invent
    up`` writes its run.mcap) exported: ``/scan`` and ``/imu`` with their types, one message each
    per sample at the time it carries; the out-of-order sample refused and counted."""
    keys = Keys()
    recording = tmp_path / "run.mcap"
    writer = McapWriter(recording)
    for index in range(10):
        stamp_ns = index * 10 * MS
        wheels = TimedDoubleSeq(tm=Time.from_nanoseconds(stamp_ns), data=[0.0, 0.0])
        if index % 5 == 0:
            writer.write_sample(keys.sim_scan, encode(_scan(stamp_ns, [1.0, None, 2.0])), stamp_ns)
        writer.write_sample(keys.sim_imu, encode(_imu(stamp_ns)), stamp_ns)
        writer.write_sample(keys.sim_clock, encode(wheels), stamp_ns)
    writer.write_sample(keys.sim_imu, encode(_imu(0)), 100 * MS)
    writer.close()
    config = load_config()
    result, refused = export_run(recording, tmp_path / "bag", [ExportedRobot(config, bridge_graph(config, environ={}))])
    assert refused == {keys.sim_imu: 1}
    assert result.counts["/scan"] == 2 and result.counts["/imu"] == 10
    with Reader(tmp_path / "bag") as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert (types["/scan"], types["/imu"]) == (interfaces.LASER_SCAN, interfaces.IMU)
        stamps = []
        for connection, timestamp, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/scan"]
        ):
            scan = ros_client.TYPESTORE.deserialize_cdr(raw, connection.msgtype)
            assert list(scan.ranges) == [1.0, math.inf, 2.0]
            stamps.append((timestamp, scan.header.stamp.nanosec))
    assert stamps == [(0, 0), (50 * MS, 50 * MS)]


# -- the bridge on a zenoh network, fed by hand -------------------------------------------------

FLEET = """world = "empty"
[[robots]]
name = "rh0"
[[robots]]
name = "rh1"
namespace = "robot1"
"""
NAMESPACES = {"rh0": "/rh0", "rh1": "/robot1"}
DOMAIN = 0


@dataclass
class Bridges:
    endpoint: str
    session: zenoh.Session
    recorder: ros_client.Recorder
    fleet_file: Path
    stamp_ns: dict[str, int]

    def feed(self, steps: int = 1, scan: bool = True) -> None:
        """Each robot's next ``steps`` steps of 10 ms: a scan (if ``scan``), an IMU sample, then the
        clock, as the simulator publishes them."""
        for _ in range(steps):
            for robot, keys in ((robot, Keys(robot)) for robot in NAMESPACES):
                stamp_ns = self.stamp_ns[robot] = self.stamp_ns[robot] + 10 * MS
                tm = Time.from_nanoseconds(stamp_ns)
                if scan:
                    self.session.put(keys.sim_scan, encode(_scan(stamp_ns, [1.0, None, 0.5 + len(robot) / 10])))
                self.session.put(keys.sim_imu, encode(_imu(stamp_ns, gyro_z=0.1 if robot == "rh0" else 0.2)))
                self.session.put(keys.sim_clock, encode(TimedDoubleSeq(tm=tm, data=[0.0, 0.0])))
            time.sleep(0.01)

    def status(self, robot: str) -> dict[str, Any]:
        ok, status = call(self.session, Keys(robot).status(Service.ROS2))
        assert ok
        return status


@pytest.fixture(scope="module")
def bridges(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bridges]:
    """``invent ros2 --fleet`` (two robots, one process) on a router of the module's own; the test's
    session stands in for the simulators and records the ROS domain from before the bridges start."""
    directory = tmp_path_factory.mktemp("ros2-sensors")
    fleet_file = directory / "fleet.toml"
    fleet_file.write_text(FLEET)
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        with InventProcess("ros2", "--fleet", str(fleet_file), "--connect", endpoint, drain=True) as process:
            state = Bridges(endpoint, session, recorder, fleet_file, dict.fromkeys(NAMESPACES, 0))
            for robot in NAMESPACES:
                wait_until(lambda r=robot: call(session, Keys(r).status(Service.ROS2))[0], 30.0, f"{robot}'s bridge")
            yield state
            code, _out, err = process.stop()
        recorder.close()
    assert code == 0, err[-3000:]


@pytest.mark.slow
def test_each_robots_scan_and_imu_are_in_the_graph_under_its_namespace_with_sensor_qos(bridges):
    expected = {
        (f"{namespace}/{topic}".replace("/", "%"), ros_client.key_type(interface), SENSOR_QOS)
        for namespace in NAMESPACES.values()
        for topic, interface in TYPES.items()
    }

    def publishers() -> set[tuple[str, str, str]]:
        tokens = ros_client.graph_tokens(bridges.session, DOMAIN)
        return {(chunks[9], "/".join(chunks[10:12]), chunks[12]) for chunks in tokens if chunks[5] == "MP"}

    found = wait_until(lambda: (seen := publishers()) >= expected and seen, 10.0, f"the publishers {expected}")
    assert expected <= found


@pytest.mark.slow
def test_a_ros_client_decodes_each_robots_scan_and_imu_in_its_namespace(bridges):
    bridges.feed(20)
    for robot, namespace in NAMESPACES.items():
        wait_until(lambda n=namespace: len(bridges.recorder.of(f"{n}/imu")) >= 20, 10.0, f"{namespace}/imu")
        scans = bridges.recorder.of(f"{namespace}/scan")
        assert len(scans) >= 20 and {s.key for s in scans} == {
            ros_client.topic_key(DOMAIN, f"{namespace}/scan", interfaces.LASER_SCAN)
        }
        for sample in scans:
            assert sample.attachment is not None and len(sample.attachment) == wire.ATTACHMENT_LENGTH
        scan = ros_client.TYPESTORE.deserialize_cdr(scans[-1].payload, interfaces.LASER_SCAN)
        assert scan.header.frame_id == "base_scan", "in its namespace, frames unprefixed (Nav2's layout)"
        assert list(scan.ranges) == pytest.approx([1.0, math.inf, 0.5 + len(robot) / 10])
        imu = ros_client.TYPESTORE.deserialize_cdr(bridges.recorder.of(f"{namespace}/imu")[-1].payload, interfaces.IMU)
        assert imu.header.frame_id == "imu_link" and imu.angular_velocity.z == (0.1 if robot == "rh0" else 0.2)
        stamps = [
            ros_client.TYPESTORE.deserialize_cdr(s.payload, interfaces.IMU).header.stamp.nanosec
            for s in bridges.recorder.of(f"{namespace}/imu")
        ]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps), "each sample once, in order"
        assert bridges.status(robot)["published"][f"{namespace}/scan"] == len(scans)


@pytest.mark.slow
def test_each_robots_sensor_frames_are_on_its_tf_static_for_a_late_subscriber(bridges):
    topics = {f"{namespace}/tf_static": "tf2_msgs/msg/TFMessage" for namespace in NAMESPACES.values()}
    for namespace, payload in ros_client.cached_samples(bridges.session, DOMAIN, topics, 10.0).items():
        static = ros_client.TYPESTORE.deserialize_cdr(payload, "tf2_msgs/msg/TFMessage")
        tree = {t.child_frame_id: t.header.frame_id for t in static.transforms}
        assert tree["base_scan"] == tree["imu_link"] == "base_link", namespace


@pytest.mark.slow
def test_a_malformed_non_finite_or_out_of_order_sensor_sample_is_counted_and_the_bridge_lives_on(bridges):
    keys = Keys("rh1")
    bridges.feed(1)
    last_ns = bridges.stamp_ns["rh1"]
    forgeries = [
        (keys.sim_scan, b"{not json", None),
        (keys.sim_scan, encode(_scan(last_ns + MS, [1.0])).replace(b"[1.0]", b"[1e999]"), "out of range"),
        (keys.sim_imu, encode(_imu(last_ns)), "not after the last imu's"),
        (keys.sim_scan, encode(_scan(last_ns - MS, [1.0])), "not after the last scan's"),
    ]
    published = bridges.status("rh1")["published"]
    for key, payload, reason in forgeries:
        counted = bridges.status("rh1")["bad_input"]["by_key"].get(key, {}).get("count", 0)
        bridges.session.put(key, payload)
        bridges.feed(1, scan=False)
        entry = wait_until(
            lambda k=key, c=counted: (
                (e := bridges.status("rh1")["bad_input"]["by_key"].get(k)) and e["count"] > c and e
            ),
            10.0,
            f"{key}: {reason}",
        )
        assert reason is None or reason in entry["last_reason"], entry
    status = bridges.status("rh1")
    assert status["internal_errors"] == 0
    assert status["published"]["/robot1/scan"] == published["/robot1/scan"], "no forged scan published"
    before = len(bridges.recorder.of("/robot1/scan"))
    bridges.feed(3)
    wait_until(lambda: len(bridges.recorder.of("/robot1/scan")) >= before + 3, 10.0, "the next good scans")


@pytest.mark.slow
def test_invent_record_ros2_records_each_robots_scan_and_imu(bridges, tmp_path):
    """The bag holds every scan and IMU sample the bridges published once its subscriptions reached
    the router: every one of them, or all but the first few (whose routing to a subscription
    just declared in another process nothing here can see), up to the last one fed."""
    fed = 30
    bag = tmp_path / "bag"
    with InventProcess(
        "record",
        "--ros2",
        "--fleet",
        str(bridges.fleet_file),
        "-o",
        str(bag),
        "--connect",
        bridges.endpoint,
        drain=True,
    ) as recording:
        wait_until(lambda: "into the bag" in recording.stderr_so_far(), 30.0, "the recorder's subscriptions")
        published = {f"{n}/{t}": len(bridges.recorder.of(f"{n}/{t}")) for n in NAMESPACES.values() for t in TYPES}
        bridges.feed(fed)
        # the bridges' last samples reached this test's subscription: the recorder's, beside it on the
        # same router, has them too
        for topic, before in published.items():
            wait_until(lambda t=topic, b=before: len(bridges.recorder.of(t)) >= b + fed, 10.0, f"{topic} published")
        code, _out, err = recording.stop(30)
    assert code == 0, err[-3000:]
    last_ns = {namespace: bridges.stamp_ns[robot] for robot, namespace in NAMESPACES.items()}
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        stamps: dict[str, list[int]] = {}
        sensor_topics = [c for c in reader.connections if c.msgtype in TYPES.values()]
        for connection, _timestamp, raw in reader.messages(connections=sensor_topics):
            header = ros_client.TYPESTORE.deserialize_cdr(raw, connection.msgtype).header
            stamps.setdefault(connection.topic, []).append(header.stamp.sec * 1_000_000_000 + header.stamp.nanosec)
    for namespace in NAMESPACES.values():
        assert types[f"{namespace}/scan"] == interfaces.LASER_SCAN and types[f"{namespace}/imu"] == interfaces.IMU
        for topic in ("scan", "imu"):
            recorded = stamps[f"{namespace}/{topic}"]
            tail = [last_ns[namespace] - k * 10 * MS for k in reversed(range(len(recorded)))]
            assert recorded == tail and len(recorded) >= fed - 10, (namespace, topic, len(recorded))
