"""ROS 2 bags and the bridge's mapping, piece by piece (services/recording/rosbag.py,
services/recording/ros2_record.py, services/ros2/outputs.py): the bounds of ``[record]`` on a bag
(split by size and by simulated time into files one ``metadata.yaml`` lists, stopped by its size,
its simulated duration or a disk running low, and saying so), the bag of the bridges' journals,
the data keys of the bridge's topics read back, the TF layouts and ``/clock`` of one bridge, and
bad input on the wire kept out of a recorded bag. Fast: one zenoh session at most.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import msgspec
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from rosbags.rosbag2 import Reader

from schemas.codec import BadInput
from schemas.messages import LaserScan, Time, TimedDoubleSeq, TimedPosition
from services.config import Config, RecordConfig, load_config
from services.config.run_sections import RecordKeep
from services.recording.ros2_record import GraphRecorder
from services.recording.rosbag import (
    DROPPED_DATA,
    STOPPED_AT_DATA,
    STOPPED_DATA,
    BagWriter,
    bag_topics,
    topic_of_key,
    write_bag_from_journals,
)
from services.ros2 import core, interfaces, wire
from services.ros2.graph import PUBLICATIONS, bridge_graph
from services.ros2.outputs import RosOutputs
from services.ros2.sensors import laser_scan
from services.runtime.journal import STOPPED_KEY, Journal, journal_path
from services.runtime.session import free_port, open_session, session_config
from tests import ros_client
from tests.harness import refused, wait_until

MS = 1_000_000
CLOCK_BYTES = len(interfaces.serialize(core.clock(0)))
"""A /clock message's CDR, encapsulation header included."""
FLEET_ROBOT = {"ros2.namespace": "/rh1", "robot.name": "rh1"}


def _bridge(**overrides: object):
    return bridge_graph(load_config(overrides=dict(overrides)), environ={})


def _clock_topic():
    return next(topic for topic in bag_topics(_bridge()).values() if topic.name == "/clock")


def _write_clocks(writer: BagWriter, count: int, period_ns: int = 10 * MS) -> None:
    topic = _clock_topic()
    for index in range(count):
        writer.write(topic, interfaces.serialize(core.clock(index * period_ns)), index * period_ns)


def _metadata(path: Path) -> dict:
    return yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def _clock_stamps(path: Path) -> list[int]:
    with Reader(path) as reader:
        return [timestamp for _c, timestamp, _raw in reader.messages()]


def test_a_bag_splits_by_simulated_time_into_files_one_metadata_lists(tmp_path):
    path = tmp_path / "bag"
    writer = BagWriter(path, RecordConfig(split_duration=0.25))
    _write_clocks(writer, 100)
    result = writer.close()
    assert [file.name for file in result.files] == [f"bag_{index}.mcap" for index in range(4)]
    metadata = _metadata(path)
    assert metadata["relative_file_paths"] == [file.name for file in result.files]
    assert [entry["message_count"] for entry in metadata["files"]] == [25, 25, 25, 25]
    assert metadata["message_count"] == 100 and metadata["custom_data"] is None
    assert metadata["topics_with_message_count"][0]["message_count"] == 100
    assert metadata["duration"]["nanoseconds"] == 990 * MS
    assert _clock_stamps(path) == [index * 10 * MS for index in range(100)], "rosbags reads every file, in order"
    assert sorted(p.name for p in path.iterdir()) == [
        "bag_0.mcap",
        "bag_1.mcap",
        "bag_2.mcap",
        "bag_3.mcap",
        "metadata.yaml",
    ]


def test_a_bag_splits_by_size(tmp_path):
    writer = BagWriter(tmp_path / "bag", RecordConfig(split_size=CLOCK_BYTES * 40 / 1e6))
    _write_clocks(writer, 100)
    assert [entry["message_count"] for entry in _metadata(writer.close().path)["files"]] == [40, 40, 20]


@pytest.mark.parametrize(
    ("record", "kept", "reason"),
    [
        (RecordConfig(max_size=30 * CLOCK_BYTES / 1e6), 30, "record.max_size"),
        (RecordConfig(max_duration=0.5), 51, "record.max_duration"),
        (RecordConfig(min_free_disk=1e12), 0, "record.min_free_disk"),
    ],
)
def test_a_bag_stops_at_its_bounds_and_its_metadata_says_why(tmp_path, record, kept, reason):
    path = tmp_path / "bag"
    writer = BagWriter(path, record)
    _write_clocks(writer, 100)
    result = writer.close()
    assert result.messages == kept and reason in result.stopped["reason"]
    custom = _metadata(path)["custom_data"]
    assert reason in custom[STOPPED_DATA]
    assert json.loads(custom[STOPPED_AT_DATA]) == (None if kept == 0 else pytest.approx((kept - 1) * 0.01)), (
        "the simulation time of the last message kept"
    )
    with Reader(path) as reader:
        assert reader.message_count == kept


def test_a_bag_is_written_into_a_new_directory_only(tmp_path):
    (tmp_path / "bag").mkdir()
    with pytest.raises(FileExistsError):
        BagWriter(tmp_path / "bag")


def test_the_bag_of_two_bridges_journals_is_in_simulation_time_order_and_stops_where_one_stopped(tmp_path):
    journals = tmp_path / "journals"
    journals.mkdir()
    first, second = _bridge(), _bridge(**FLEET_ROBOT, **{"ros2.publish_clock": False})
    clock_key = first.key(PUBLICATIONS["clock"])
    odom_key = second.key(second.publications["odom"])
    odom = interfaces.serialize(core.string("not used: the bag keeps the payload as it is"))
    one = Journal(journal_path(journals, "rh0"))
    two = Journal(journal_path(journals, "rh1"))
    for index in range(10):
        one.write(clock_key, interfaces.serialize(core.clock(index * 10 * MS)), time_ns=index * 10 * MS)
    for index in range(5):
        two.write(odom_key, odom, time_ns=index * 20 * MS + 1)
    two.write("invent/rh1/motor/torque", b"{}", time_ns=95 * MS)  # not a ROS topic: left out
    two.write(STOPPED_KEY, msgspec.json.encode({"reason": "record.min_free_disk: 1 MB free", "journal": "x"}), 99 * MS)
    one.close()
    two.close()
    result = write_bag_from_journals(journals, tmp_path / "bag", RecordConfig())
    assert result.counts == {"/clock": 10, "/rh1/odom": 5}
    assert "min_free_disk" in result.stopped["reason"]
    stamps = _clock_stamps(tmp_path / "bag")
    assert stamps == sorted(stamps) and len(stamps) == 15


@given(st.lists(st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,8}", fullmatch=True), max_size=3), st.integers(0, 232))
def test_every_topic_the_bridge_publishes_is_read_back_from_its_data_key(names, domain):
    namespace = "/".join(names)
    for prefixed in (False, True):
        config = load_config(
            overrides={"ros2.namespace": namespace, "ros2.tf": "prefixed" if prefixed else "namespaced"}
        )
        bridge = bridge_graph(config, environ={"ROS_DOMAIN_ID": str(domain)})
        for key, topic in bag_topics(bridge).items():
            assert topic_of_key(key) == topic
            assert wire.parse_data_key(key)[0] == domain


def test_a_key_the_bridge_does_not_publish_on_is_bad_input():
    odom = _bridge().key(PUBLICATIONS["odom"])
    for key in (
        odom.replace("Odometry_", "Twist_"),  # another type
        odom.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64,  # another hash
        odom.replace("/odom/", "/cmd_vel/"),  # not a topic the bridge publishes
        "invent/rh0/motor/torque",
        "0/odom",
    ):
        with pytest.raises(BadInput):
            topic_of_key(key)


def _wheels(stamp_ns: int, left: float, right: float) -> TimedDoubleSeq:
    return TimedDoubleSeq(tm=Time.from_nanoseconds(stamp_ns), data=[left, right])


@pytest.mark.parametrize("layout", ["namespaced", "prefixed"])
def test_a_namespaced_bridges_tf_is_in_its_namespace_or_prefixed_on_the_shared_tf(layout):
    config = load_config(overrides={"ros2.namespace": "rh1", "ros2.tf": layout, "ros2.publish_clock": False})
    bridge = bridge_graph(config, environ={})
    names = {topic: bridge.name(entity) for topic, entity in bridge.publications.items()}
    shared = layout == "prefixed"
    assert names == {
        "odom": "/rh1/odom",
        "tf": "/tf" if shared else "/rh1/tf",
        "tf_static": "/tf_static" if shared else "/rh1/tf_static",
        "joint_states": "/rh1/joint_states",
        "robot_description": "/rh1/robot_description",
        "scan": "/rh1/scan",
        "imu": "/rh1/imu",
        "map": "/rh1/map",
        "costmap": "/rh1/global_costmap/costmap",
        "plan": "/rh1/plan",
    }, "no /clock: another bridge publishes it; the sensors in the namespace"
    outputs = RosOutputs(config, bridge)
    prefix = "rh1/" if shared else ""
    static, description = outputs.latched()
    assert {t.child_frame_id for t in static.message.transforms} == {
        f"{prefix}{link}" for link in ("front_caster", "rear_caster", "base_scan", "imu_link")
    }
    assert 'name="base_link"' in description.message.data, "the URDF's links as named: RViz adds a TF prefix"
    outputs.take_localized(TimedPosition(tm=Time.from_nanoseconds(0), id=[], x=1.0, y=2.0, theta=0.0, error=[]))
    assert outputs.take_wheels(_wheels(0, 0.0, 0.0)).outgoing
    outputs.take_localized(TimedPosition(tm=Time.from_nanoseconds(0), id=[], x=1.0, y=2.0, theta=0.0, error=[]))
    taken = outputs.take_wheels(_wheels(20 * MS, 0.1, 0.1))
    assert [message.topic for message in taken.outgoing] == ["odom", "tf", "joint_states"]
    odom, tf, _joints = (message.message for message in taken.outgoing)
    assert (odom.header.frame_id, odom.child_frame_id) == (f"{prefix}odom", f"{prefix}base_link")
    pairs = {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}
    assert pairs == {
        (f"{prefix}odom", f"{prefix}base_link"),
        (f"{prefix}base_link", f"{prefix}left_wheel"),
        (f"{prefix}base_link", f"{prefix}right_wheel"),
        ("map", f"{prefix}odom"),
    }, "map is the world's, shared by every robot"
    assert all(message.stamp_ns == 20 * MS for message in taken.outgoing)


def test_a_bridge_that_publishes_clock_ticks_it_at_clock_rate_on_the_simulators_grid():
    outputs = RosOutputs(Config(), _bridge())
    ticks = []
    for step in range(0, 45 * MS, 5 * MS):
        ticks += [m.stamp_ns for m in outputs.take_wheels(_wheels(step, 0.0, 0.0)).outgoing if m.topic == "clock"]
    assert ticks == [0, 10 * MS, 20 * MS, 30 * MS, 40 * MS]


def test_the_live_recorder_keeps_bad_input_on_a_bridges_key_out_of_the_bag(tmp_path):
    """Malformed CDR, a sample without rmw_zenoh's attachment, a stamp that is not a time, one that
    jumps an hour ahead: each counted under its key, none in the bag; the good samples around them are."""
    bridge = _bridge()
    clock_key = bridge.key(PUBLICATIONS["clock"])
    gid = os.urandom(16)

    def clock(stamp_ns: int, nanosec: int | None = None) -> bytes:
        time = ros_client.message(
            "builtin_interfaces/msg/Time",
            sec=stamp_ns // 10**9,
            nanosec=stamp_ns % 10**9 if nanosec is None else nanosec,
        )
        return ros_client.cdr(ros_client.message("rosgraph_msgs/msg/Clock", clock=time))

    samples = [
        (clock(0), ros_client.attachment(1, gid)),
        (b"\x00\x01\x00\x00\x01", ros_client.attachment(2, gid)),  # malformed CDR
        (clock(10 * MS), None),  # a plain zenoh put
        (clock(0, nanosec=2 * 10**9), ros_client.attachment(3, gid)),  # not a time
        (clock(3600 * 10**9), ros_client.attachment(4, gid)),  # an hour ahead
        (clock(10 * MS), ros_client.attachment(5, gid)),
    ]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(session_config(listen=[endpoint], mode="router")) as session:
        writer = BagWriter(tmp_path / "bag")
        recorder = GraphRecorder(session, [bridge], writer, Config().input.stamp_horizon_ns)
        publisher = session.declare_publisher(clock_key)
        for payload, attachment in samples:
            publisher.put(payload, **({} if attachment is None else {"attachment": attachment}))

        def taken() -> bool:
            recorder.spin_once()
            return writer.messages + sum(recorder.refused.values()) == len(samples)

        wait_until(taken, 5.0, "every sample taken")
        recorder.close()
        publisher.undeclare()
    result = writer.close()
    assert recorder.refused == {clock_key: 4}
    assert _clock_stamps(result.path) == [0, 10 * MS]


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (("up", "--record-ros2", "--no-record"), "--record-ros2 without --ros2, with --no-record"),
        (("up", "--fleet", "examples/fleets/two_squares.toml", "--teleop"), "--teleop (--ros2)"),
        (("record", "--fleet", "examples/fleets/two_squares.toml"), "--fleet: it is an option of --ros2"),
        (("record", "--ros2", "invent/rh0/**"), "--ros2 with invent/rh0/**: a bag records the bridges' topics"),
        (("ros2", "--fleet", "examples/fleets/two_squares.toml", "--namespace", "x"), "--fleet with --namespace"),
        (("export", "--ros2", "no/such/run.mcap", "-o", "bag"), "no/such/run.mcap: no such file"),
    ],
)
def test_ros2_flags_that_cannot_work_exit_2_naming_them(argv, named, capsys):
    """In this process: each is refused before any session or process starts."""
    code, _out, err = refused(capsys, *argv)
    assert code == 2 and named in err, err


def test_a_bag_keeping_the_newest_removes_its_oldest_files_and_its_metadata_lists_those_left(tmp_path):
    scan_topic = next(topic for topic in bag_topics(_bridge()).values() if topic.name == "/scan")
    path = tmp_path / "bag"
    writer = BagWriter(path, RecordConfig(keep=RecordKeep.NEWEST, max_size=3, split_size=1))
    stamps = [index * 100 * MS for index in range(300)]
    for stamp_ns in stamps:
        scan = LaserScan(Time.from_nanoseconds(stamp_ns), 0.0, 0.001, 0.1, 10.0, [1.0] * 4096)
        writer.write(scan_topic, interfaces.serialize(laser_scan(scan, "base_scan", 10.0)), stamp_ns)
    result = writer.close()

    metadata = _metadata(path)
    dropped = json.loads(metadata["custom_data"][DROPPED_DATA])
    assert dropped[:2] == ["bag_0.mcap", "bag_1.mcap"], "the oldest first"
    assert metadata["relative_file_paths"] == [file.name for file in result.files]
    assert sorted(p.name for p in path.iterdir()) == sorted([*metadata["relative_file_paths"], "metadata.yaml"])
    assert sum(file.stat().st_size for file in result.files) <= 3e6
    with Reader(path) as reader:
        kept = [timestamp for _c, timestamp, _raw in reader.messages()]
    assert kept == stamps[-len(kept) :], "the newest, in order, read by rosbags"


def test_a_bag_of_journals_that_removed_files_numbers_its_own_files_in_a_row(tmp_path):
    """The journals' removed files are said in the bag's ``dropped`` (as write_bag_from_journals
    passes them), not counted among the bag's own: its files are numbered one after another."""
    scan_topic = next(topic for topic in bag_topics(_bridge()).values() if topic.name == "/scan")
    path = tmp_path / "bag"
    writer = BagWriter(path, RecordConfig(keep=RecordKeep.NEWEST, max_size=30, split_size=1))
    writer.dropped.extend(["sim.journal", "sim.1.journal", "sim.2.journal"])
    for index in range(300):
        stamp_ns = index * 100 * MS
        scan = LaserScan(Time.from_nanoseconds(stamp_ns), 0.0, 0.001, 0.1, 10.0, [1.0] * 4096)
        writer.write(scan_topic, interfaces.serialize(laser_scan(scan, "base_scan", 10.0)), stamp_ns)
    result = writer.close()
    assert [file.name for file in result.files] == [f"bag_{index}.mcap" for index in range(len(result.files))]
    assert len(result.files) > 2
