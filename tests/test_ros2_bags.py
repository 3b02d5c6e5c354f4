"""ROS 2 bags of a run, read by readers written elsewhere: rosbags' rosbag2 ``Reader`` and the
``mcap-ros2-support`` decoder (the mcap project's ROS 2 decoder) on the same files.

One short lockstep run of a two-robot fleet, ``invent up --fleet FILE --ros2 --record-ros2
--composed --engine kinematic`` (each robot the straight scenario; the bags' subject is not the
physics, and the kinematic engine takes less CPU: 3.4-3.7 s against 4.1-5.4 s measured), writes ``run.mcap`` and the bag of what the bridges
published; ``invent export --ros2 run.mcap --fleet FILE`` turns the same ``run.mcap`` into a second
bag. Both split by ``record.split_duration``, as an unattended run's would. Each bag has the fleet's topics and ROS's types and hashes, every message decodes, ``/clock``
is monotonic, each topic's messages are exactly the run's simulation steps on its rate's grid (so
the counts match the rates), and each message's timestamp is the simulation time it carries.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from schemas.codec import decode
from schemas.keys import Keys
from schemas.messages import TimedDoubleSeq
from services.recording.mcap_files import read_run
from tests import ros_client
from tests.harness import free_port, run_invent, start_up

pytestmark = pytest.mark.slow

FLEET = """world = "empty"
[[robots]]
name = "rh0"
start = { x = 0.0, y = 0.0, theta = 0.0 }
scenario = "straight"
[[robots]]
name = "rh1"
namespace = "robot1"
start = { x = 0.0, y = 3.0, theta = 0.0 }
scenario = "straight"
"""
NAMESPACES = {"rh0": "/rh0", "rh1": "/robot1"}
TOPICS = {
    "odom": "nav_msgs/msg/Odometry",
    "tf": "tf2_msgs/msg/TFMessage",
    "tf_static": "tf2_msgs/msg/TFMessage",
    "joint_states": "sensor_msgs/msg/JointState",
    "robot_description": "std_msgs/msg/String",
    "scan": "sensor_msgs/msg/LaserScan",
    "imu": "sensor_msgs/msg/Imu",
}
EXPECTED = {"/clock": "rosgraph_msgs/msg/Clock"} | {
    f"{namespace}/{topic}": interface for namespace in NAMESPACES.values() for topic, interface in TOPICS.items()
}
"""Every topic of the bag and its type: each robot's in its namespace, /clock once."""
CLOCK_PERIOD_NS = 10_000_000
STATE_PERIOD_NS = 20_000_000
"""ros2.clock_rate (100) and ros2.publish_rate (50) per simulated second, the defaults."""
SCAN_PERIOD_NS = 100_000_000
IMU_PERIOD_NS = 10_000_000
"""lidar.rate (10) and imu.rate (100) per simulated second, the defaults: a sample each, in the bag."""
BAGS = ("recorded", "exported")
SPLIT = ("--set", "record.split_duration=3")
"""The straight line takes 7.4 simulated seconds: each bag is three files, as an unattended run's would be."""


@dataclass
class Run:
    directory: Path
    bags: dict[str, Path]
    steps: dict[str, list[int]]
    """Each robot's ``sim/clock`` stamps in ``run.mcap``: the run's observed simulation steps."""


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    directory = tmp_path_factory.mktemp("ros2-bags")
    fleet = directory / "fleet.toml"
    fleet.write_text(FLEET)
    report = directory / "report"
    up = start_up(
        "--fleet", str(fleet), "--ros2", "--record-ros2", "--composed", "--engine", "kinematic",
        "--report", str(report), "--listen", f"tcp/127.0.0.1:{free_port()}", *SPLIT,
    )  # fmt: skip
    try:
        output, _ = up.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        up.kill()
        output, _ = up.communicate()
    assert up.returncode == 0, output[-3000:]
    exported = directory / "exported"
    result = run_invent(
        "export", "--ros2", str(report / "run.mcap"), "-o", str(exported), "--fleet", str(fleet), *SPLIT
    )
    assert result.returncode == 0, result.stderr
    messages = read_run(report / "run.mcap").messages
    steps = {
        robot: sorted(decode(TimedDoubleSeq, m.data).tm.to_nanoseconds() for m in messages if m.topic == key)
        for robot in NAMESPACES
        if (key := Keys(robot).sim_clock)
    }
    yield Run(directory, {"recorded": report / "rosbag2", "exported": exported}, steps)


def _read(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Every message of the bag by topic: (timestamp, message decoded with rosbags' typestore)."""
    messages: dict[str, list[tuple[int, Any]]] = {}
    with Reader(path) as reader:
        for connection, timestamp, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (timestamp, ros_client.TYPESTORE.deserialize_cdr(raw, connection.msgtype))
            )
    return messages


def _raw(path: Path, topic: str) -> list[tuple[int, bytes]]:
    """(timestamp, CDR) of every message of ``topic`` in the bag."""
    with Reader(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [(timestamp, bytes(raw)) for _c, timestamp, raw in reader.messages(connections=connections)]


def _ns(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


@pytest.mark.parametrize("bag", BAGS)
def test_the_bag_has_the_fleets_topics_with_ros_types_hashes_and_qos_in_its_metadata(run, bag):
    path = run.bags[bag]
    metadata = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["version"] == 8 and metadata["storage_identifier"] == "mcap"
    files = [f"{path.name}_{index}.mcap" for index in range(3)]
    assert metadata["relative_file_paths"] == files and all((path / file).is_file() for file in files)
    starts = [file["starting_time"]["nanoseconds_since_epoch"] for file in metadata["files"]]
    assert starts[1] - starts[0] >= 3e9 and starts[2] - starts[1] >= 3e9, "a file per 3 simulated seconds"
    topics = {
        entry["topic_metadata"]["name"]: entry["topic_metadata"] for entry in metadata["topics_with_message_count"]
    }
    assert {name: meta["type"] for name, meta in topics.items()} == EXPECTED
    for name, meta in topics.items():
        assert meta["serialization_format"] == "cdr"
        assert meta["type_description_hash"] == ros_client.TYPESTORE.hash_rihs01(meta["type"]), name
    latched = yaml.safe_load(topics["/rh0/tf_static"]["offered_qos_profiles"])
    assert latched[0]["durability"] == 1 and latched[0]["depth"] == 1, "tf_static offered transient local"
    with Reader(path) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == EXPECTED
        assert reader.message_count == metadata["message_count"] == sum(c.msgcount for c in reader.connections)


@pytest.mark.parametrize("bag", BAGS)
def test_every_message_decodes_with_mcap_ros2_support_as_with_rosbags(run, bag):
    path = run.bags[bag]
    with Reader(path) as reader:
        total = reader.message_count
    clocks = []
    decoded = 0
    for file in sorted(path.glob("*.mcap")):
        with file.open("rb") as stream:
            for schema, channel, _message, ros in make_reader(
                stream, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages():
                assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
                assert schema.name == EXPECTED[channel.topic]
                decoded += 1
                if channel.topic == "/clock":
                    clocks.append(ros.clock.sec * 1_000_000_000 + ros.clock.nanosec)
    assert decoded == total
    assert clocks == [_ns(clock.clock) for _t, clock in _read(path)["/clock"]], "both readers read the same /clock"


@pytest.mark.parametrize("bag", BAGS)
def test_each_topic_is_the_runs_simulation_steps_on_its_rates_grid_and_clock_is_monotonic(run, bag):
    messages = _read(run.bags[bag])
    clock = [_ns(message.clock) for _t, message in messages["/clock"]]
    assert clock == sorted(clock) and len(set(clock)) == len(clock), "/clock monotonic"
    assert clock == [step for step in run.steps["rh0"] if step % CLOCK_PERIOD_NS == 0], (
        "/clock at every 100 Hz tick of the run, from its first step to its last: counts match the rate"
    )
    for robot, namespace in NAMESPACES.items():
        grid = [step for step in run.steps[robot] if step % STATE_PERIOD_NS == 0]
        for topic in ("odom", "joint_states"):
            stamps = [_ns(message.header.stamp) for _t, message in messages[f"{namespace}/{topic}"]]
            assert stamps == grid, f"{namespace}/{topic} at every 50 Hz tick of the run"
        assert len(messages[f"{namespace}/tf"]) == len(grid)
        for topic, period_ns in (("scan", SCAN_PERIOD_NS), ("imu", IMU_PERIOD_NS)):
            stamps = [_ns(message.header.stamp) for _t, message in messages[f"{namespace}/{topic}"]]
            assert stamps == list(range(0, run.steps[robot][-1] + 1, period_ns)), f"{namespace}/{topic}: every sample"
        assert len(messages[f"{namespace}/tf_static"]) == len(messages[f"{namespace}/robot_description"]) == 1


@pytest.mark.parametrize("bag", BAGS)
def test_each_message_is_at_the_simulation_time_it_carries(run, bag):
    for topic, messages in _read(run.bags[bag]).items():
        for timestamp, message in messages:
            if topic == "/clock":
                carried = _ns(message.clock)
            elif topic.endswith(("/tf", "/tf_static")):
                carried = max(_ns(transform.header.stamp) for transform in message.transforms)
            elif topic.endswith("/robot_description"):
                carried = 0  # published once, before the first step
            else:
                carried = _ns(message.header.stamp)
            assert timestamp == carried, topic


def test_the_recorded_and_exported_odometry_are_the_same_messages(run):
    """One mapping (services/ros2/outputs.py) for the live bridge and the export: the continuous
    odometry of the same wheel angles is the same, bit for bit."""
    for namespace in NAMESPACES.values():
        recorded, exported = (_raw(run.bags[bag], f"{namespace}/odom") for bag in BAGS)
        assert recorded == exported and len(recorded) > 300
    recorded_tf = _read(run.bags["recorded"])["/robot1/tf"]
    tf = {frame for _t, m in recorded_tf for frame in ((t.header.frame_id, t.child_frame_id) for t in m.transforms)}
    assert ("odom", "base_link") in tf and ("map", "odom") in tf, "each namespace's tree, frames as named"
