"""The drive's map, costmap and plan in ROS 2 (services/ros2/core.py, outputs.py, service.py):
``drive/map`` as ``map`` (nav_msgs/OccupancyGrid, latched as Nav2's map_server offers it),
``drive/costmap`` as ``global_costmap/costmap`` (OccupancyGrid, latched as Nav2's costmap publisher
offers it), ``drive/plan`` as ``plan`` (nav_msgs/Path, as Nav2's planner_server offers it): their
type hashes equal to the ones ROS ships (tests/data/ros2_interfaces, copied from ROS's ``nav_msgs``
wheel), their QoS, names and frames, the cells in nav_msgs' order, each pose of a plan oriented
along it, bad input refused (tests/test_ros2_navigation_bridge.py: the bridge on a zenoh network).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from schemas.codec import BadInput, decode, encode
from schemas.messages import Time, TimedDoubleSeq
from schemas.navigation import GoalPlan, OccupancyGrid
from services.config import load_config
from services.ros2 import core, graph, interfaces, wire
from services.ros2.graph import bridge_graph
from services.ros2.outputs import RosOutputs
from tests import ros_client
from tests.test_ros2_sensors import DOMAIN

SHIPPED = Path(__file__).parent / "data" / "ros2_interfaces"
MS = 1_000_000
S = 1_000 * MS
LATCHED_QOS = ":1:,1:,:,:,,"
"""Reliable, transient local, keep-last 1 in a token: map_server's ``map``, Nav2's costmap."""
PLAN_QOS = "::,1:,:,:,,"
"""Reliable, volatile, keep-last 1: Nav2's planner_server's ``plan`` (Jazzy, Kilted)."""
TOPICS = {
    "map": ("map", interfaces.OCCUPANCY_GRID, LATCHED_QOS),
    "costmap": ("global_costmap/costmap", interfaces.OCCUPANCY_GRID, LATCHED_QOS),
    "plan": ("plan", interfaces.PATH, PLAN_QOS),
}
"""Each navigation topic: its name in the namespace, its type, its token's QoS."""
CELLS = bytes(range(101)) + bytes([255])
"""The bytes a cell may be: 0..100, and 255 (-1, unknown)."""


def _shipped_hash(name: str) -> str:
    """The RIHS01 hash ROS computed for ``name``, from its type description (``type_hashes``)."""
    package, _msg, type_name = name.split("/")
    description = json.loads((SHIPPED / package / "msg" / f"{type_name}.json").read_text())
    (entry,) = [e for e in description["type_hashes"] if e["type_name"] == name]
    return entry["hash_string"]


def _grid(stamp_ns: int, width: int, height: int, data: bytes, **fields: Any) -> OccupancyGrid:
    values = {"resolution": 0.05, "origin_x": -2.0, "origin_y": 1.5, **fields}
    return OccupancyGrid(tm=Time.from_nanoseconds(stamp_ns), width=width, height=height, data=data, **values)


def _plan(stamp_ns: int, points: list[tuple[float, float]], goal_id: str = "g1") -> GoalPlan:
    return GoalPlan(tm=Time.from_nanoseconds(stamp_ns), goal_id=goal_id, points=points)


def _outputs(**overrides: Any) -> RosOutputs:
    config = load_config(overrides=overrides)
    return RosOutputs(config, bridge_graph(config, environ={}))


def _yaw(quaternion: Any) -> float:
    assert quaternion.x == quaternion.y == 0.0
    return 2.0 * math.atan2(quaternion.z, quaternion.w)


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * S + int(stamp.nanosec)


def _key_type(name: str) -> str:
    """``nav_msgs/msg/Path`` -> ``nav_msgs::msg::dds_::Path_/RIHS01_<ROS's shipped hash>``, as in a key or token."""
    return ros_client.nav_key(DOMAIN, "topic", name).split("/", 2)[2]


def _round_trip(message: Any) -> Any:
    """What a ROS node decodes of a message the bridge publishes (ROS's own types, from the
    descriptions ROS ships)."""
    return ros_client.nav_decode(interfaces.serialize(message), message.__msgtype__)


# -- types, QoS, names ------------------------------------------------------------------------


@pytest.mark.parametrize("name", [interfaces.OCCUPANCY_GRID, interfaces.PATH])
def test_the_map_and_plan_types_hashes_are_the_ones_ros_ships(name):
    shipped = _shipped_hash(name)
    assert shipped.startswith("RIHS01_") and len(shipped) == 7 + 64
    assert interfaces.interface(name).type_hash == shipped
    for store in (Stores.ROS2_JAZZY, Stores.ROS2_KILTED):
        assert get_typestore(store).hash_rihs01(name) == shipped, store
    assert ros_client.NAV_TYPESTORE.hash_rihs01(name) == shipped, "the description's own types hash to it"
    bridge = bridge_graph(load_config(overrides={"ros2.namespace": "rh1"}), environ={})
    for topic, (_name, interface, _qos) in TOPICS.items():
        if interface == name:
            assert bridge.key(bridge.publications[topic]).endswith(f"/{shipped}")


@pytest.mark.parametrize(("namespace", "layout"), [("", "namespaced"), ("rh1", "namespaced"), ("rh1", "prefixed")])
def test_the_navigation_topics_are_nav2s_names_in_the_namespace_with_nav2s_qos(namespace, layout):
    config = load_config(overrides={"ros2.namespace": namespace, "ros2.tf": layout})
    bridge = bridge_graph(config, environ={})
    prefix = f"/{namespace}" if namespace else ""
    for topic, (name, interface, qos) in TOPICS.items():
        entity = bridge.publications[topic]
        assert bridge.name(entity) == f"{prefix}/{name}", "in the namespace, as the other topics (TF aside)"
        assert (entity.interface, entity.qos.token_chunk()) == (interface, qos)
        assert bridge.key(entity) == ros_client.nav_key(0, f"{prefix}/{name}", interface)
    assert set(graph.NAVIGATION_TOPICS) == set(TOPICS)
    assert wire.LATCHED.token_chunk() == LATCHED_QOS and wire.PLAN.token_chunk() == PLAN_QOS


# -- the messages -------------------------------------------------------------------------------

grids = st.tuples(st.integers(1, 12), st.integers(1, 12)).flatmap(
    lambda size: st.tuples(
        st.just(size), st.lists(st.sampled_from(CELLS), min_size=size[0] * size[1], max_size=size[0] * size[1])
    )
)


@given(grids, st.floats(0.01, 1.0), st.floats(-100.0, 100.0), st.floats(-100.0, 100.0))
def test_a_map_is_an_occupancy_grid_in_map_with_its_cells_in_nav_msgs_order(grid, resolution, origin_x, origin_y):
    (width, height), cells = grid
    outputs = _outputs()
    message = _grid(
        1_500 * MS, width, height, bytes(cells), resolution=resolution, origin_x=origin_x, origin_y=origin_y
    )
    (out,) = outputs.take_map(message)
    assert (out.topic, out.stamp_ns) == ("map", 1_500 * MS)
    decoded = _round_trip(out.message)
    assert (decoded.header.frame_id, _stamp_ns(decoded.header.stamp)) == ("map", 1_500 * MS)
    info = decoded.info
    assert _stamp_ns(info.map_load_time) == 1_500 * MS, "map_server's: when the map was loaded"
    assert (info.width, info.height) == (width, height)
    assert info.resolution == pytest.approx(resolution, rel=1e-6)
    position, orientation = info.origin.position, info.origin.orientation
    assert (position.x, position.y, position.z) == (origin_x, origin_y, 0.0)
    assert (orientation.x, orientation.y, orientation.z, orientation.w) == (0.0, 0.0, 0.0, 1.0)
    assert decoded.data.dtype == np.int8 and len(decoded.data) == width * height
    for row in range(height):
        for col in range(width):
            cell = cells[row * width + col]
            assert decoded.data[col + row * width] == (-1 if cell == 255 else cell), (col, row)


def test_a_costmap_is_an_occupancy_grid_in_map_as_nav2s_costmap_publisher_makes_it():
    outputs = _outputs(**{"ros2.namespace": "rh1", "ros2.tf": "prefixed"})
    cells = bytes([0, 10, 100, 255, 99, 0])
    (out,) = outputs.take_costmap(_grid(2 * S, 3, 2, cells, resolution=0.1, origin_x=-1.0, origin_y=-0.5))
    assert (out.topic, out.stamp_ns) == ("costmap", 2 * S)
    decoded = _round_trip(out.message)
    assert decoded.header.frame_id == "map", "the world's map, unprefixed on a shared /tf too"
    assert _stamp_ns(decoded.header.stamp) == 2 * S
    assert _stamp_ns(decoded.info.map_load_time) == 0, "Nav2's costmap publisher leaves it unset"
    assert (decoded.info.width, decoded.info.height, decoded.info.origin.position.x) == (3, 2, -1.0)
    assert list(decoded.data) == [0, 10, 100, -1, 99, 0], "row 0 (the lowest y) first, as the drive's"


def test_a_plan_is_a_path_in_map_each_pose_oriented_along_it_and_the_last_as_it_is_reached():
    outputs = _outputs()
    points = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (1.0, 1.0), (0.0, 1.0), (0.0, 1.00001)]
    (out,) = outputs.take_plan(_plan(3 * S + 20 * MS, points))
    assert (out.topic, out.stamp_ns) == ("plan", 3 * S + 20 * MS)
    decoded = _round_trip(out.message)
    assert (decoded.header.frame_id, _stamp_ns(decoded.header.stamp)) == ("map", 3 * S + 20 * MS)
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in decoded.poses] == [
        (x, y, 0.0) for x, y in points
    ]
    assert {(p.header.frame_id, _stamp_ns(p.header.stamp)) for p in decoded.poses} == {("map", 3 * S + 20 * MS)}
    headings = [_yaw(p.pose.orientation) for p in decoded.poses]
    # to the next point; a point on the next one (or less than 0.1 mm from it) as that one; the
    # last as it is reached (the plan has no goal heading)
    assert headings == pytest.approx([0.0, math.pi / 2, math.pi, math.pi, math.pi, math.pi])


@given(st.lists(st.tuples(st.integers(-50, 50), st.integers(-50, 50)), min_size=2, max_size=30, unique=True))
def test_each_poses_heading_is_the_direction_to_the_next_point_and_the_last_the_one_it_is_reached_in(cells):
    points = [(x / 10.0, y / 10.0) for x, y in cells]
    headings = core.path_headings(points)
    for index in range(len(points)):
        (x0, y0), (x1, y1) = points[index : index + 2] if index + 1 < len(points) else points[index - 1 :]
        assert headings[index] == math.atan2(y1 - y0, x1 - x0), index


def test_an_empty_plan_is_a_path_without_poses_and_a_lone_point_faces_x():
    outputs = _outputs()
    (ended,) = outputs.take_plan(_plan(S, []))
    decoded = _round_trip(ended.message)
    assert decoded.header.frame_id == "map" and len(decoded.poses) == 0, "the goal ended: RViz clears its path"
    assert core.path_headings([(2.0, 3.0)]) == [0.0] and core.path_headings([(1.0, 1.0), (1.0, 1.0)]) == [0.0, 0.0]


@pytest.mark.parametrize(
    ("take", "feed", "reason"),
    [
        ("map", [_grid(S, 1, 1, b"\x00", resolution=1e39)], "no positive float32"),
        ("costmap", [_grid(S, 1, 1, b"\x00", resolution=1e-50)], "no positive float32"),
        ("costmap", [_grid(2 * S, 1, 1, b"\x00"), _grid(2 * S, 1, 1, b"\x00")], "not after the last costmap's"),
        ("costmap", [_grid(2 * S, 1, 1, b"\x00"), _grid(S, 1, 1, b"\x00")], "not after the last costmap's"),
        ("map", [_grid(2 * S, 1, 1, b"\x00"), _grid(S, 1, 1, b"\x00")], "before the last map's"),
        ("plan", [_plan(2 * S, [(0.0, 0.0)]), _plan(S, [])], "before the last plan's"),
        ("plan", [_plan(2**31 * S, [(0.0, 0.0)])], "int32"),
        ("map", [_grid(2**31 * S, 1, 1, b"\x00")], "int32"),
    ],
)
def test_a_map_costmap_or_plan_out_of_order_or_that_ros_cannot_hold_is_bad_input(take, feed, reason):
    outputs = _outputs()
    handle = {"map": outputs.take_map, "costmap": outputs.take_costmap, "plan": outputs.take_plan}[take]
    *good, bad = feed
    for message in good:
        assert handle(message)
    with pytest.raises(BadInput, match=reason):
        handle(bad)


def test_a_latched_message_sent_again_is_taken_and_a_new_simulator_starts_the_stamps_again():
    outputs = _outputs()
    assert outputs.take_map(_grid(2 * S, 1, 1, b"\x00")) and outputs.take_map(_grid(2 * S, 1, 1, b"\x00"))
    assert outputs.take_plan(_plan(2 * S, [(0.0, 0.0)])) and outputs.take_plan(_plan(2 * S, []))
    outputs.take_wheels(TimedDoubleSeq(tm=Time.from_nanoseconds(5 * S), data=[0.0, 0.0]))
    with pytest.raises(BadInput, match="stamp_horizon ahead of the clock"):
        outputs.take_costmap(_grid(7 * S, 1, 1, b"\x00"))
    assert outputs.take_costmap(_grid(5 * S, 1, 1, b"\x00"))
    outputs.clock.restart.simulator_appeared()
    assert outputs.take_wheels(TimedDoubleSeq(tm=Time.from_nanoseconds(0), data=[0.0, 0.0])).restarted
    for take in (outputs.take_map, outputs.take_costmap):
        assert take(_grid(10 * MS, 1, 1, b"\x00")), "a new simulator's stamps start again"
    assert outputs.take_plan(_plan(10 * MS, []))


def test_an_occupancy_grid_whose_data_does_not_match_its_size_never_reaches_the_bridge():
    payload = encode(_grid(S, 2, 2, bytes(4))).replace(b'"height":2', b'"height":3')
    with pytest.raises(BadInput, match="bytes of data"):
        decode(OccupancyGrid, payload)
