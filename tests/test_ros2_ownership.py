"""The bridge's ownership switches (``ros2.enable_odom_tf``, ``enable_map_odom_tf``,
``enable_wheel_tf``, ``navigate_to_pose``): each hands its part to a node of ROS's own.

Pure: what each switch keeps off ``tf`` (and in the bridge's own TF tree, where goals are given),
the graph's ``tf`` publisher and ``goal_pose`` subscription. End to end, a ROS client in rmw_zenoh's
wire format (tests/ros_client.py) against a composed lockstep run on the kinematic engine, with the
defaults and with the four switches off: every transform and the action, or none of them; ``/odom``
at ``ros2.publish_rate`` either way.
"""

from __future__ import annotations

import itertools
import subprocess
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.config import ConfigError, load_config
from services.ros2.graph import GOAL_POSE, bridge_graph
from services.ros2.outputs import RosOutputs
from tests import ros_client
from tests.harness import invent_command, peer_session, running_router

MS = 1_000_000
SWITCHES = ("enable_odom_tf", "enable_map_odom_tf", "enable_wheel_tf", "navigate_to_pose")
ALL_OFF = {f"ros2.{switch}": False for switch in SWITCHES}
ODOM, MAP, WHEELS = ("odom", "base_link"), ("map", "odom"), {("base_link", "left_wheel"), ("base_link", "right_wheel")}
TRANSFORMS = {"enable_odom_tf": {ODOM}, "enable_map_odom_tf": {MAP}, "enable_wheel_tf": WHEELS}
"""The ``parent -> child`` pairs on ``tf`` each switch is for."""


def _outputs(**overrides: Any) -> RosOutputs:
    config = load_config(overrides=overrides)
    return RosOutputs(config, bridge_graph(config, environ={}))


def _published(outputs: RosOutputs) -> dict[str, Any]:
    """What a localized pose and two wheel samples give: each topic's last message."""
    outputs.latched()
    published: dict[str, Any] = {}
    for stamp_ns, angle in ((0, 0.0), (20 * MS, 0.1)):
        outputs.take_localized(
            TimedPosition(tm=Time.from_nanoseconds(stamp_ns), id=[], x=1.0, y=2.0, theta=0.5, error=[])
        )
        for message in outputs.take_wheels(TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), [angle, angle])).outgoing:
            published[message.topic] = message.message
    return published


def test_the_switches_are_on_by_default_and_a_value_not_boolean_is_refused_naming_it():
    settings = load_config().ros2
    assert all(getattr(settings, switch) for switch in SWITCHES)
    with pytest.raises(ConfigError, match="ros2.enable_odom_tf"):
        load_config(overrides={"ros2.enable_odom_tf": "sometimes"})


@pytest.mark.parametrize("switch", sorted(TRANSFORMS))
def test_each_tf_switch_keeps_its_transforms_off_tf_and_in_the_bridges_own_tree(switch):
    outputs = _outputs(**{f"ros2.{switch}": False})
    published = _published(outputs)
    pairs = {(t.header.frame_id, t.child_frame_id) for t in published["tf"].transforms}
    assert pairs == ({ODOM, MAP} | WHEELS) - TRANSFORMS[switch]
    assert {"odom", "joint_states"} <= set(published), "/odom and /joint_states either way"
    in_map = outputs.tree.lookup("map", "right_wheel")
    assert in_map.translation[2] == pytest.approx(0.0), "the tree still holds every transform, published or not"


def test_with_every_tf_switch_off_the_bridge_publishes_no_tf_at_all():
    overrides = {key: value for key, value in ALL_OFF.items() if "tf" in key}
    outputs = _outputs(**overrides)
    assert "tf" not in outputs.topics and "tf" not in _published(outputs)
    assert {"tf_static", "odom", "joint_states"} <= set(outputs.topics)


def test_with_navigate_to_pose_off_the_graph_has_no_goal_pose_and_no_action():
    assert GOAL_POSE in bridge_graph(load_config(), environ={}).subscriptions
    bridge = bridge_graph(load_config(overrides={"ros2.navigate_to_pose": False}), environ={})
    assert not bridge.navigate_to_pose and GOAL_POSE not in bridge.subscriptions


def _run(directory: Path, overrides: dict[str, bool]) -> tuple[list[ros_client.Received], set[str]]:
    """A composed lockstep run of the straight scenario on the kinematic engine, with ``--set`` of
    each override: every ROS sample of domain 0 and every graph token seen meanwhile."""
    sets = [arg for key, value in overrides.items() for arg in ("--set", f"{key}={str(value).lower()}")]
    tokens: set[str] = set()
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, "0/**")
        watcher = session.liveliness().declare_subscriber(
            "@ros2_lv/0/**",
            lambda sample: tokens.add(str(sample.key_expr)) if sample.kind == zenoh.SampleKind.PUT else None,
            history=True,
        )
        result = subprocess.run(
            invent_command(
                "up",
                "--ros2",
                "--composed",
                "--engine",
                "kinematic",
                "--scenario",
                "straight",
                "--no-record",
                "--connect",
                endpoint,
                *sets,
            ),
            cwd=directory,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        watcher.undeclare()
        samples = recorder.take()
        recorder.close()
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return samples, set(tokens)


def _seen(samples: list[ros_client.Received], tokens: set[str]) -> dict[str, Any]:
    tf_key, odom_key = (
        ros_client.topic_key(0, topic, name)
        for topic, name in (("tf", "tf2_msgs/msg/TFMessage"), ("odom", "nav_msgs/msg/Odometry"))
    )
    pairs = {
        (t.header.frame_id, t.child_frame_id)
        for sample in samples
        if sample.key == tf_key
        for t in ros_client.TYPESTORE.deserialize_cdr(sample.payload, "tf2_msgs/msg/TFMessage").transforms
    }
    stamps = [
        (odom := ros_client.TYPESTORE.deserialize_cdr(sample.payload, "nav_msgs/msg/Odometry")).header.stamp.sec
        * 1_000_000_000
        + odom.header.stamp.nanosec
        for sample in samples
        if sample.key == odom_key
    ]
    return {
        "pairs": pairs,
        "odom stamps": stamps,
        "action tokens": {token for token in tokens if "%navigate_to_pose%_action%" in token},
        "tf publisher": any(token.split("/")[5] == "MP" and "/%tf/" in token for token in tokens),
        "goal_pose": any("/%goal_pose/" in token for token in tokens),
        "action replies": [s.key for s in samples if "/navigate_to_pose/_action/" in s.key],
    }


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    return {
        name: _seen(*_run(tmp_path_factory.mktemp(name), overrides))
        for name, overrides in (("defaults", {}), ("all off", ALL_OFF))
    }


def _at_publish_rate(stamps: list[int]) -> bool:
    period_ns = round(1e9 / load_config().ros2.publish_rate)
    return len(stamps) > 50 and all(b - a == period_ns for a, b in itertools.pairwise(stamps))


@pytest.mark.slow
@pytest.mark.kinematic
def test_with_the_defaults_a_ros_client_sees_every_transform_the_action_and_odom_at_its_rate(runs):
    seen = runs["defaults"]
    assert {ODOM, MAP} | WHEELS <= seen["pairs"], seen["pairs"]
    assert len(seen["action tokens"]) == 5, "send_goal, cancel_goal, get_result, feedback, status"
    assert seen["tf publisher"] and seen["goal_pose"]
    assert _at_publish_rate(seen["odom stamps"]), "every 20 ms of simulation time"


@pytest.mark.slow
@pytest.mark.kinematic
def test_with_the_four_switches_off_a_ros_client_sees_none_of_them_and_odom_at_its_rate(runs):
    seen = runs["all off"]
    assert not seen["pairs"] & ({ODOM, MAP} | WHEELS), seen["pairs"]
    assert seen["action tokens"] == set() and not seen["goal_pose"], "no navigate_to_pose, no goal_pose"
    assert not seen["tf publisher"] and seen["action replies"] == [], "no /tf publisher: nothing to publish"
    assert _at_publish_rate(seen["odom stamps"]), "every 20 ms of simulation time, as with the defaults"
