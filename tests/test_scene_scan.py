"""The lidar's scan in Foxglove (services/recording/scene.py, pure): each ``sim/scan`` becomes a
``foxglove.LaserScan`` in the lidar's frame and the transform that puts that frame on the robot at
the ``[lidar]`` mount, read back through Foxglove's own compiled protobuf schemas; and a scan that
is bad input is dropped and counted by a view, kept as published (not shown) by a recorder."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan as FoxgloveLaserScan
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput, encode
from schemas.keys import Keys
from schemas.messages import MAX_SCAN_RAYS, LaserScan, Time
from schemas.topics import Topic
from services.config import Config, LidarConfig, load_config
from services.recording.record import SceneBuilder, Sink
from services.recording.scene import LIDAR_FRAME, ROBOT_FRAME, SCAN_TOPIC, TRANSFORMS_TOPIC, Scene
from services.runtime.logs import BadInputCounter

CONFIG = Config()
KEYS = Keys(CONFIG.robot.name)
MS = 1_000_000


def _scan(stamp_ns: int, ranges: list[float | None], angle_min: float = -math.pi, increment: float = 0.1) -> LaserScan:
    return LaserScan(
        tm=Time.from_nanoseconds(stamp_ns),
        angle_min=angle_min,
        angle_increment=increment,
        range_min=0.12,
        range_max=3.5,
        ranges=ranges,
    )


def _shown(scene: Scene, scan: LaserScan) -> tuple[Any, Any]:
    """(the transform, the laser scan) as Foxglove decodes them."""
    ((tf_topic, transforms), (scan_topic, shown)) = scene.add(Topic.SIM_SCAN, scan)
    assert tf_topic == TRANSFORMS_TOPIC and scan_topic == scene.topics[SCAN_TOPIC]
    return FrameTransforms.FromString(transforms.encode()), FoxgloveLaserScan.FromString(shown.encode())


def test_a_scan_is_a_laser_scan_in_the_lidar_frame_placed_at_the_mount():
    lidar = LidarConfig(x=0.05, y=-0.02, z=0.12, yaw=math.pi / 2)
    scene = Scene(CONFIG.robot, CONFIG.sim, lidar=lidar)
    transforms, scan = _shown(scene, _scan(1_500 * MS, [1.0, None, 2.5], angle_min=-0.2, increment=0.1))

    (mount,) = transforms.transforms
    assert (mount.parent_frame_id, mount.child_frame_id) == (ROBOT_FRAME, LIDAR_FRAME)
    assert (mount.translation.x, mount.translation.y, mount.translation.z) == (0.05, -0.02, 0.12)
    assert (mount.rotation.z, mount.rotation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    assert (mount.timestamp.seconds, mount.timestamp.nanos) == (1, 500_000_000)
    assert scan.frame_id == LIDAR_FRAME and scene.topics[SCAN_TOPIC] == SCAN_TOPIC
    assert (scan.timestamp.seconds, scan.timestamp.nanos) == (1, 500_000_000), "the scan's own stamp"
    assert scan.pose.orientation.w == 1.0 and scan.pose.position.x == 0.0, "the scan at the frame's origin"
    assert (scan.start_angle, scan.end_angle) == pytest.approx((-0.2, 0.0)), "bearings of the first and last rays"
    assert list(scan.ranges) == [1.0, math.inf, 2.5], "nothing within range_max: +inf, as ROS has it"
    assert list(scan.intensities) == []


@given(
    st.lists(st.one_of(st.none(), st.floats(0.0, 100.0)), max_size=MAX_SCAN_RAYS),
    st.floats(-math.pi, math.pi),
    st.floats(1e-4, 0.1),
)
def test_foxglove_puts_every_ray_where_the_scan_says(ranges, angle_min, increment):
    """Foxglove spreads the ranges evenly from ``start_angle`` to ``end_angle``: ray i lands at
    ``angle_min + i * angle_increment``, with its range, for any scan."""
    _transforms, scan = _shown(Scene(CONFIG.robot, CONFIG.sim), _scan(0, ranges, angle_min, increment))
    assert list(scan.ranges) == [math.inf if r is None else r for r in ranges]
    if len(ranges) > 1:
        step = (scan.end_angle - scan.start_angle) / (len(ranges) - 1)
        assert scan.start_angle == angle_min and step == pytest.approx(increment, rel=1e-9)
    else:
        assert scan.end_angle == scan.start_angle == angle_min


def test_a_scan_whose_last_angle_overflows_is_bad_input():
    with pytest.raises(BadInput, match="not finite"):
        Scene(CONFIG.robot, CONFIG.sim).add(Topic.SIM_SCAN, _scan(0, [1.0, 1.0, 1.0], increment=1.7e308))


def test_a_fleets_scans_are_each_in_its_robots_own_lidar_frame():
    fleet = [load_config(overrides={"robot.name": name, "lidar.x": 0.1 * index}) for index, name in enumerate("ab")]
    shown: list[tuple[str, Any]] = []
    builder = SceneBuilder(
        fleet[0], Sink(lambda *_: None, lambda topic, message, *_: shown.append((topic, message))), fleet
    )
    for name in "ab":
        builder.take(Keys(name).sim_scan, encode(_scan(0, [1.0, 2.0])), 0)
    scans = {topic: FoxgloveLaserScan.FromString(m.encode()) for topic, m in shown if topic.endswith(SCAN_TOPIC)}
    assert {topic: scan.frame_id for topic, scan in scans.items()} == {
        "/a/scan": "a/base_scan",
        "/b/scan": "b/base_scan",
    }
    mounts = [
        (t.parent_frame_id, t.child_frame_id, t.translation.x)
        for topic, message in shown
        if topic == TRANSFORMS_TOPIC
        for t in FrameTransforms.FromString(message.encode()).transforms
    ]
    assert mounts == [("a/base_link", "a/base_scan", 0.0), ("b/base_link", "b/base_scan", 0.1)]


def _changed(**fields: Any) -> bytes:
    """A good scan's JSON with ``fields`` changed."""
    return json.dumps({**json.loads(encode(_scan(0, [1.0, 2.0]))), **fields}).encode()


BAD_SCANS = {
    "not JSON": b"{",
    "a range that is not finite": _changed(ranges=[1.0, "inf"]).replace(b'"inf"', b"1e999"),
    "a negative range": _changed(ranges=[1.0, -2.0]),
    "range limits upside down": _changed(range_max=0.01),
    "too many rays": _changed(ranges=[1.0] * (MAX_SCAN_RAYS + 1)),
    "hits of another length": _changed(bodies=["box"], hits=[0]),
    "an unknown field": _changed(intensities=[1.0, 1.0]),
    "an overflowing last angle": _changed(angle_increment=1.7e308, ranges=[1.0, 1.0, 1.0]),
}


def _taken(payload: bytes, bad_input: BadInputCounter | None) -> dict[str, list[str]]:
    """What a builder (a view's: with ``bad_input``) hands on of a scan ``payload`` then a good one."""
    seen: dict[str, list[str]] = {"samples": [], "shown": []}
    sink = Sink(lambda key, *_: seen["samples"].append(key), lambda topic, *_: seen["shown"].append(topic))
    builder = SceneBuilder(CONFIG, sink, bad_input=bad_input)
    builder.take(KEYS.sim_scan, payload, 0)
    builder.take(KEYS.sim_scan, encode(_scan(MS, [1.0])), 0)
    return seen


def test_a_bad_scan_is_dropped_and_counted_by_a_view_and_kept_unshown_by_a_recorder():
    good = [KEYS.sim_scan], [TRANSFORMS_TOPIC, SCAN_TOPIC]
    for name, payload in BAD_SCANS.items():
        counter = BadInputCounter("view")
        assert _taken(payload, counter) == {"samples": good[0], "shown": good[1]}, f"{name}: dropped, then goes on"
        assert counter.status().by_key[KEYS.sim_scan].count == 1, name
        recorded = _taken(payload, None)
        assert recorded == {"samples": [KEYS.sim_scan, *good[0]], "shown": good[1]}, f"{name}: recorded, not shown"
