"""The drive's map, costmap and plan in ROS 2 on a real zenoh network: the real ``invent ros2`` fed by
a stand-in drive and simulator. A ROS client's side (tests/ros_client.py, its types and hashes from
ROS's type descriptions alone) sees each topic in the graph once the drive publishes it, gets the map
as a ROS subscriber started late does (from the bridge's cache, the drive's map itself published
before the bridge started), decodes the costmap and the plan, bad input counted with the bridge living
on, and the bag that ``invent up --record-ros2`` makes of what a bridge journals
(tests/test_ros2_navigation.py: the types, QoS, names and messages).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import pytest
import zenoh
from rosbags.rosbag2 import Reader

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq
from schemas.navigation import OccupancyGrid
from services.config import load_config
from services.recording.rosbag import write_bag_from_journals
from services.ros2 import interfaces
from tests import ros_client
from tests.harness import InventProcess, call, peer_session, running_router, wait_until
from tests.test_ros2_navigation import LATCHED_QOS, MS, PLAN_QOS, TOPICS, _grid, _key_type, _plan, _stamp_ns, _yaw
from tests.test_ros2_sensors import DOMAIN, FLEET, NAMESPACES

# -- the bridge on a zenoh network, fed by a stand-in drive -------------------------------------

MAP_CELLS = bytes([0, 0, 100, 255, 0, 100, 0, 255, 50, 0, 0, 100])
"""A 4 x 3 map, its rows from the lowest y: what the ROS side must get in this order."""


class LatchedStandIn:
    """A latched key as the drive publishes it (``Node.latched_publisher``): each message put, and
    the last one the answer to a query (what a bridge started late asks)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.session, self.key = session, key
        self.last: bytes | None = None
        self._queryable = session.declare_queryable(key, self._answer)

    def _answer(self, query: zenoh.Query) -> None:
        if self.last is not None:
            query.reply(self.key, self.last)

    def put(self, message: msgspec.Struct) -> None:
        self.last = encode(message)
        self.session.put(self.key, self.last)

    def close(self) -> None:
        self._queryable.undeclare()


@dataclass
class Drive:
    """The stand-ins of each robot's simulator (its clock) and drive (map, costmap, plan)."""

    endpoint: str
    session: zenoh.Session
    recorder: ros_client.Recorder
    fleet_file: Path | None
    maps: dict[str, LatchedStandIn]
    plans: dict[str, LatchedStandIn]
    clock_ns: dict[str, int]

    def tick(self, robot: str, steps: int = 1) -> int:
        """``steps`` more clock samples of ``robot``'s simulator, 10 ms apart; the last one's time."""
        for _ in range(steps):
            self.clock_ns[robot] += 10 * MS
            tm = Time.from_nanoseconds(self.clock_ns[robot])
            self.session.put(Keys(robot).sim_clock, encode(TimedDoubleSeq(tm=tm, data=[0.0, 0.0])))
            time.sleep(0.005)
        return self.clock_ns[robot]

    def costmap(self, robot: str, message: OccupancyGrid | bytes) -> None:
        """A ``drive/costmap``, then a clock sample (the bridge takes the newest costmap when it ticks)."""
        self.session.put(Keys(robot).drive_costmap, message if isinstance(message, bytes) else encode(message))
        time.sleep(0.02)  # a pace: the bridge reads its newest-only costmap after the clock, so the clock comes later
        self.tick(robot)

    def status(self, robot: str) -> dict[str, Any]:
        ok, status = call(self.session, Keys(robot).status(Service.ROS2))
        assert ok
        return status

    def received(self, robot: str, topic: str) -> list[Any]:
        """What the ROS side received of ``robot``'s ``topic`` (a key of :data:`TOPICS`), decoded."""
        name, interface, _qos = TOPICS[topic]
        key = ros_client.nav_key(DOMAIN, f"{NAMESPACES[robot]}/{name}", interface)
        return [ros_client.nav_decode(s.payload, interface) for s in self.recorder.take() if s.key == key]


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Drive]:
    """``invent ros2 --fleet`` (two robots, one process) on a router of the module's own, started
    after rh1's drive published its map; the test's session stands in for the simulators and drives
    and records the ROS domain."""
    directory = tmp_path_factory.mktemp("ros2-navigation")
    fleet_file = directory / "fleet.toml"
    fleet_file.write_text(FLEET)
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        maps = {robot: LatchedStandIn(session, Keys(robot).drive_map) for robot in NAMESPACES}
        plans = {robot: LatchedStandIn(session, Keys(robot).drive_plan) for robot in NAMESPACES}
        maps["rh1"].put(_grid(0, 4, 3, MAP_CELLS, resolution=0.5, origin_x=-1.0, origin_y=-0.75))
        with InventProcess("ros2", "--fleet", str(fleet_file), "--connect", endpoint, drain=True) as process:
            state = Drive(endpoint, session, recorder, fleet_file, maps, plans, dict.fromkeys(NAMESPACES, 0))
            for robot in NAMESPACES:
                wait_until(lambda r=robot: call(session, Keys(r).status(Service.ROS2))[0], 30.0, f"{robot}'s bridge")
            yield state
            code, _out, err = process.stop()
        for stand_in in (*maps.values(), *plans.values()):
            stand_in.close()
        recorder.close()
    assert code == 0, err[-3000:]


def _navigation_publishers(session: zenoh.Session) -> dict[str, tuple[str, str]]:
    """The navigation topics' publishers in the graph: name -> (type and hash as in a key, QoS)."""
    names = {f"{ns}/{name}".replace("/", "%") for ns in NAMESPACES.values() for name, _i, _q in TOPICS.values()}
    return {
        chunks[9]: ("/".join(chunks[10:12]), chunks[12])
        for chunks in ros_client.graph_tokens(session, DOMAIN)
        if chunks[5] == "MP" and chunks[9] in names
    }


def _publisher_of(session: zenoh.Session, name: str) -> tuple[str, str]:
    """The token of the publisher of ``name`` (``%robot1%plan``), once it is in the graph."""
    return wait_until(lambda: _navigation_publishers(session).get(name), 10.0, f"a publisher of {name}")


@pytest.mark.slow
def test_a_bridge_offers_the_map_once_its_drive_publishes_one_and_a_late_ros_subscriber_gets_it(drive):
    """rh1's drive published its map before the bridge started: the bridge asked for it and
    publishes it; rh0's bridge offers no navigation topic until its drive publishes. A ROS
    subscriber started after both maps were published gets each from the bridge's cache."""
    expected = _key_type(interfaces.OCCUPANCY_GRID), LATCHED_QOS
    found = wait_until(lambda: "%robot1%map" in (seen := _navigation_publishers(drive.session)) and seen, 10.0, "map")
    assert found["%robot1%map"] == expected
    assert not [name for name in found if name.startswith("%rh0%")], "rh0's drive published nothing yet"
    drive.maps["rh0"].put(_grid(20 * MS, 2, 1, bytes([100, 0]), resolution=0.25, origin_x=3.0, origin_y=4.0))
    found = wait_until(lambda: "%rh0%map" in (seen := _navigation_publishers(drive.session)) and seen, 10.0, "rh0 map")
    assert found["%rh0%map"] == expected
    topics = {f"{ns}/map": interfaces.OCCUPANCY_GRID for ns in NAMESPACES.values()}
    late = ros_client.cached_samples(drive.session, DOMAIN, topics, 10.0, key_of=ros_client.nav_key)
    rh1 = ros_client.nav_decode(late["/robot1/map"], interfaces.OCCUPANCY_GRID)
    assert rh1.header.frame_id == "map" and _stamp_ns(rh1.header.stamp) == 0
    assert (rh1.info.width, rh1.info.height, rh1.info.resolution) == (4, 3, 0.5)
    assert (rh1.info.origin.position.x, rh1.info.origin.position.y, rh1.info.origin.orientation.w) == (-1.0, -0.75, 1.0)
    assert list(rh1.data) == [-1 if cell == 255 else cell for cell in MAP_CELLS]
    rh0 = ros_client.nav_decode(late["/rh0/map"], interfaces.OCCUPANCY_GRID)
    assert (list(rh0.data), rh0.info.origin.position.x, _stamp_ns(rh0.info.map_load_time)) == ([100, 0], 3.0, 20 * MS)
    assert drive.status("rh0")["published"]["/rh0/map"] == drive.status("rh1")["published"]["/robot1/map"] == 1


@pytest.mark.slow
def test_the_costmap_reaches_ros_with_its_size_origin_and_cells_and_a_late_subscriber_gets_the_last(drive):
    now_ns = drive.tick("rh1", 5)
    cells = bytes([0, 1, 2, 3, 4, 5, 98, 99, 100, 255, 0, 0])
    drive.costmap("rh1", _grid(now_ns, 3, 4, cells, resolution=0.1, origin_x=-0.15, origin_y=-0.2))
    (costmap,) = wait_until(lambda: drive.received("rh1", "costmap"), 10.0, "/robot1/global_costmap/costmap")
    assert costmap.header.frame_id == "map" and _stamp_ns(costmap.header.stamp) == now_ns
    assert (costmap.info.width, costmap.info.height) == (3, 4)
    assert costmap.info.resolution == pytest.approx(0.1, rel=1e-6)
    assert (costmap.info.origin.position.x, costmap.info.origin.position.y) == (-0.15, -0.2)
    assert list(costmap.data) == [0, 1, 2, 3, 4, 5, 98, 99, 100, -1, 0, 0]
    newer_ns = drive.tick("rh1", 100)
    drive.costmap("rh1", _grid(newer_ns, 1, 1, bytes([100])))
    wait_until(lambda: len(drive.received("rh1", "costmap")) == 2, 10.0, "the second costmap")
    assert _publisher_of(drive.session, "%robot1%global_costmap%costmap") == (
        _key_type(interfaces.OCCUPANCY_GRID),
        LATCHED_QOS,
    )
    topic = {"/robot1/global_costmap/costmap": interfaces.OCCUPANCY_GRID}
    late = ros_client.cached_samples(drive.session, DOMAIN, topic, 10.0, key_of=ros_client.nav_key)
    last = ros_client.nav_decode(late["/robot1/global_costmap/costmap"], interfaces.OCCUPANCY_GRID)
    assert (_stamp_ns(last.header.stamp), list(last.data)) == (newer_ns, [100]), "the last, not the first"


@pytest.mark.slow
def test_the_plan_reaches_ros_as_a_path_oriented_along_it_and_empty_when_the_goal_ends(drive):
    now_ns = drive.tick("rh1")
    points = [(0.0, 0.0), (0.5, 0.5), (0.5, 1.5), (-0.5, 1.5)]
    drive.plans["rh1"].put(_plan(now_ns, points, goal_id="0123456789abcdef0123456789abcdef"))
    (plan,) = wait_until(lambda: drive.received("rh1", "plan"), 10.0, "/robot1/plan")
    assert plan.header.frame_id == "map" and _stamp_ns(plan.header.stamp) == now_ns
    assert [(p.pose.position.x, p.pose.position.y) for p in plan.poses] == points
    assert all(p.header.frame_id == "map" and _stamp_ns(p.header.stamp) == now_ns for p in plan.poses)
    assert [_yaw(p.pose.orientation) for p in plan.poses] == pytest.approx([math.pi / 4, math.pi / 2, math.pi, math.pi])
    assert _publisher_of(drive.session, "%robot1%plan") == (_key_type(interfaces.PATH), PLAN_QOS)
    drive.plans["rh1"].put(_plan(drive.tick("rh1"), []))
    ended = wait_until(lambda: (got := drive.received("rh1", "plan"))[1:] and got[-1], 10.0, "the empty plan")
    assert len(ended.poses) == 0 and ended.header.frame_id == "map"


@pytest.mark.slow
def test_a_bad_map_costmap_or_plan_is_counted_and_dropped_and_the_bridge_lives_on(drive):
    keys = Keys("rh1")
    last_ns = drive.tick("rh1", 2)
    good = encode(_grid(last_ns, 2, 2, bytes(4)))
    drive.costmap("rh1", good)
    wait_until(lambda: drive.status("rh1")["published"].get("/robot1/global_costmap/costmap"), 10.0, "a costmap")
    navigation = [f"/robot1/{name}" for name, _interface, _qos in TOPICS.values()]
    published = {topic: drive.status("rh1")["published"].get(topic) for topic in navigation}
    forgeries = [
        (keys.drive_costmap, good.replace(b'"height":2', b'"height":3'), "bytes of data"),
        (keys.drive_costmap, good, "not after the last costmap's"),
        (keys.drive_costmap, b"{not json", None),
        (keys.drive_map, encode(_grid(last_ns, 1, 1, b"\x00", resolution=1e39)), "no positive float32"),
        (keys.drive_map, encode(_grid(last_ns, 1, 1, b"\x00")).replace(b'"data":"AA=="', b'"data":"ZQ=="'), "-1"),
        (keys.drive_plan, encode(_plan(last_ns, [(0.0, 0.0)])).replace(b"[0.0,0.0]", b"[1e999,0.0]"), None),
        (keys.drive_plan, encode(_plan(last_ns, [])).replace(b'"goal_id":"g1"', b'"goal_id":"a/b"'), None),
    ]
    for key, payload, reason in forgeries:
        counted = drive.status("rh1")["bad_input"]["by_key"].get(key, {}).get("count", 0)
        drive.session.put(key, payload)

        def counted_once_more(k: str = key, c: int = counted) -> dict[str, Any] | None:
            drive.tick("rh1")  # the bridge takes a newest-only costmap at its clock's ticks
            entry = drive.status("rh1")["bad_input"]["by_key"].get(k)
            return entry if entry and entry["count"] > c else None

        entry = wait_until(counted_once_more, 10.0, f"{key}: {reason}")
        assert reason is None or reason in entry["last_reason"], entry
    status = drive.status("rh1")
    assert status["internal_errors"] == 0
    assert {topic: status["published"].get(topic) for topic in navigation} == published, "nothing forged published"
    drive.costmap("rh1", _grid(drive.tick("rh1"), 1, 1, bytes([7])))
    wait_until(lambda: any(list(c.data) == [7] for c in drive.received("rh1", "costmap")), 10.0, "the next costmap")


@pytest.mark.slow
def test_invent_record_ros2_records_the_map_from_the_cache_and_the_costmap_and_plan(drive, tmp_path):
    """``invent record --ros2`` started after rh1's map was published: the map from the bridge's
    cache (a transient-local subscriber), the costmap and the plan as they come. The recorder's
    subscriptions reach the bridge through the router some time after it says it records (nothing
    here sees when): of the costmaps and plans fed one after another, the last ones are in the bag."""
    bag = tmp_path / "bag"
    assert drive.fleet_file is not None
    with InventProcess(
        "record", "--ros2", "--fleet", str(drive.fleet_file), "-o", str(bag), "--connect", drive.endpoint, drain=True
    ) as recording:
        wait_until(lambda: "into the bag" in recording.stderr_so_far(), 30.0, "the recorder's subscriptions")
        for _ in range(5):
            costmaps, plans = len(drive.received("rh1", "costmap")), len(drive.received("rh1", "plan"))
            now_ns = drive.tick("rh1", 10)
            drive.costmap("rh1", _grid(now_ns, 1, 2, bytes([100, 255])))
            drive.plans["rh1"].put(_plan(now_ns, [(0.0, 0.0), (0.0, -1.0)]))
            wait_until(lambda c=costmaps: len(drive.received("rh1", "costmap")) > c, 10.0, "the costmap published")
            wait_until(lambda p=plans: len(drive.received("rh1", "plan")) > p, 10.0, "the plan published")
        code, _out, err = recording.stop(30)
    assert code == 0, err[-3000:]
    messages = _bag_messages(bag)
    (_map_time, grid), *_ = messages["/robot1/map"]
    assert list(grid.data) == [-1 if cell == 255 else cell for cell in MAP_CELLS]
    assert (now_ns, [100, -1]) in [(t, list(c.data)) for t, c in messages["/robot1/global_costmap/costmap"]]
    (plan,) = [p for t, p in messages["/robot1/plan"] if t == now_ns]
    assert [_yaw(p.pose.orientation) for p in plan.poses] == pytest.approx([-math.pi / 2, -math.pi / 2])
    with Reader(bag) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert qos["/robot1/map"][0].durability.value == 1, "offered transient local, as the bridge offers it"


# -- the bag of what a bridge journals (invent up --record-ros2) --------------------------------


@pytest.fixture(scope="module")
def journal_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``invent ros2 --bag-journal DIR`` (one robot, no namespace), fed a map, a costmap and two
    plans, stopped, and the bag made of its journal as ``invent up --record-ros2`` makes it."""
    directory = tmp_path_factory.mktemp("ros2-navigation-bag")
    journals = directory / "bag-journals"
    journals.mkdir()
    keys = Keys("rh0")
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        latched = {"map": LatchedStandIn(session, keys.drive_map), "plan": LatchedStandIn(session, keys.drive_plan)}
        feed = Drive(endpoint, session, recorder, None, {"rh0": latched["map"]}, {"rh0": latched["plan"]}, {"rh0": 0})
        with InventProcess("ros2", "--connect", endpoint, "--bag-journal", str(journals), drain=True) as process:
            wait_until(lambda: call(session, keys.status(Service.ROS2))[0], 30.0, "the bridge")
            latched["map"].put(_grid(0, 4, 3, MAP_CELLS))
            feed.tick("rh0", 50)
            feed.costmap("rh0", _grid(500 * MS, 2, 1, bytes([0, 100])))
            latched["plan"].put(_plan(510 * MS, [(0.0, 0.0), (1.0, 0.0)]))
            latched["plan"].put(_plan(520 * MS, []))
            for topic, count in (("map", 1), ("costmap", 1), ("plan", 2)):
                name, interface, _qos = TOPICS[topic]
                key = ros_client.nav_key(DOMAIN, f"/{name}", interface)
                wait_until(lambda k=key, n=count: len([s for s in recorder.take() if s.key == k]) >= n, 10.0, topic)
            code, _out, err = process.stop()
        for stand_in in latched.values():
            stand_in.close()
        recorder.close()
    assert code == 0, err[-3000:]
    bag = directory / "rosbag2"
    write_bag_from_journals(journals, bag, load_config().record)
    return bag


def _bag_messages(bag: Path) -> dict[str, list[tuple[int, Any]]]:
    """Each topic's (timestamp, decoded message) in the bag, of the navigation types."""
    messages: dict[str, list[tuple[int, Any]]] = {}
    with Reader(bag) as reader:
        wanted = [c for c in reader.connections if c.msgtype in (interfaces.OCCUPANCY_GRID, interfaces.PATH)]
        for connection, timestamp, raw in reader.messages(connections=wanted):
            message = ros_client.nav_decode(raw, connection.msgtype)
            messages.setdefault(connection.topic, []).append((timestamp, message))
    return messages


@pytest.mark.slow
def test_the_map_and_the_plan_land_in_the_bag_of_what_the_bridge_journals(journal_bag):
    messages = _bag_messages(journal_bag)
    ((map_time, grid),) = messages["/map"]
    assert map_time == 0 and list(grid.data) == [-1 if cell == 255 else cell for cell in MAP_CELLS]
    plans = messages["/plan"]
    assert [(timestamp, len(plan.poses)) for timestamp, plan in plans] == [(510 * MS, 2), (520 * MS, 0)]


@pytest.mark.slow
def test_the_costmap_lands_in_the_bag_of_what_the_bridge_journals(journal_bag):
    ((timestamp, costmap),) = _bag_messages(journal_bag)["/global_costmap/costmap"]
    assert timestamp == 500 * MS and list(costmap.data) == [0, 100]
