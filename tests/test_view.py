"""``invent view``: a real Foxglove WebSocket client on the view of a real loop, and the layout
that goes with it.

The loop is ``invent up --loop --composed`` connected to this test's own router; ``invent view``
connects to the same router and serves on a port of its own choosing (``--port 0``), which it
says in its log line. The client speaks the Foxglove WebSocket protocol: it offers both its
subprotocol names, ``foxglove.sdk.v1`` (the one foxglove-sdk's server accepts) and the older
``foxglove.websocket.v1``, takes ``serverInfo`` and the ``advertise`` ops, subscribes, and reads
the binary ``messageData`` frames: opcode 0x01, the subscription id (uint32 LE), the log time
(uint64 LE ns), the payload.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import struct
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import foxglove
import msgspec
import pytest
import websockets
import zenoh
from foxglove.messages import FrameTransforms
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms as FrameTransformsProto
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan as FoxgloveLaserScan
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from schemas.codec import decode, encode
from schemas.keys import Keys, Service, schema_for_key
from schemas.messages import ImuSample, LaserScan, Time, TimedDoubleSeq
from schemas.topics import Topic
from services.config import Config
from services.exits import ExitStatus
from services.recording.navigation_scene import COSTMAP_TOPIC, MAP_TOPIC
from services.recording.scene import (
    LIDAR_FRAME,
    LOCALIZATION_TOPIC,
    ODOMETRY_TOPIC,
    ROBOT_FRAME,
    SCAN_TOPIC,
    SCENE_TOPIC,
    TRANSFORMS_TOPIC,
    WHEEL_SPEEDS_SCHEMA,
    WHEEL_SPEEDS_TOPIC,
    WORLD_FRAME,
)
from services.recording.view import FoxgloveChannels, run_view
from tests.harness import REPO, call, free_port, invent_command, peer_session, running_router, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys()
"""The default robot: the one docs/foxglove/layout.json names."""
LAYOUT = REPO / "docs" / "foxglove" / "layout.json"
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
HEADER = struct.Struct("<BIQ")
"""A ``messageData`` frame's header: opcode, subscription id, log time (ns)."""
URL_LINE = re.compile(r"Foxglove live view on (ws://[\d.]+:(\d+)) ")
UNKNOWN_CHANNEL = re.compile(r'"op":"status".*Unknown channel ID: (\d+)')
STARTUP_TIMEOUT_S = 60.0
WATCH_TIMEOUT_S = 60.0
PER_SUBSCRIPTION = 3
FLOOD_STOP_S = 5.0
"""A view stops within this of SIGINT while a flood comes (``invent up`` waits 10 s before killing it)."""
FLOOD_SAMPLES = 100_000
SUBSCRIBED = {
    TRANSFORMS_TOPIC: "foxglove.FrameTransforms",
    SCENE_TOPIC: "foxglove.SceneUpdate",
    ODOMETRY_TOPIC: "foxglove.PoseInFrame",
    WHEEL_SPEEDS_TOPIC: WHEEL_SPEEDS_SCHEMA["title"],
    KEYS.sim_body_pose: TimedDoubleSeq.__name__,
    KEYS.status(Service.MOTOR): None,
    SCAN_TOPIC: "foxglove.LaserScan",
    KEYS.sim_scan: LaserScan.__name__,
    KEYS.sim_imu: ImuSample.__name__,
}
"""The channels the client subscribes to, and the schema each must have (None: schemaless)."""


SCENE_TOPICS = (
    TRANSFORMS_TOPIC,
    ODOMETRY_TOPIC,
    LOCALIZATION_TOPIC,
    SCENE_TOPIC,
    WHEEL_SPEEDS_TOPIC,
    SCAN_TOPIC,
    MAP_TOPIC,
    COSTMAP_TOPIC,
)


def served_topics(keys: Keys) -> frozenset[str]:
    """Every topic a view of ``keys.robot`` serves once its loop runs: the robot's data keys, its
    services' status keys, and the scene's topics."""
    return frozenset(
        [*(keys.topic(topic) for topic in Topic), *(keys.status(service) for service in Service), *SCENE_TOPICS]
    )


class _Process:
    """An ``invent`` subcommand whose output (stdout and stderr, one pipe) a thread reads as it comes."""

    def __init__(self, *args: str) -> None:
        self.args = args
        self.process = subprocess.Popen(
            invent_command(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        self.lines: list[str] = []
        self._pump = threading.Thread(target=lambda: self.lines.extend(self.process.stdout), daemon=True)
        self._pump.start()

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def stop(self, timeout: float = 20.0) -> int:
        """SIGINT, and its exit code once it exits (killed if it does not within ``timeout``)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"invent {' '.join(self.args)} did not stop on SIGINT:\n{self.output[-3000:]}")

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(10)
        self._pump.join(5)


@dataclass
class Watched:
    """What the client saw."""

    subprotocol: str | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The advertised channels, by topic."""
    frames: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    """(log time ns, payload) of the messages taken, by topic."""


async def _subscribe(client: Any, subscriptions: dict[int, int]) -> None:
    """Subscribe to channels: {subscription id: channel id}."""
    entries = [{"id": index, "channelId": channel} for index, channel in subscriptions.items()]
    await client.send(json.dumps({"op": "subscribe", "subscriptions": entries}))


async def _watch(url: str, topics: list[str], watched: Watched) -> None:
    async with websockets.connect(
        url, subprotocols=SUBPROTOCOLS, open_timeout=10, close_timeout=1, max_size=None
    ) as client:
        watched.subprotocol = client.subprotocol
        watched.server_info = json.loads(await client.recv())
        while not all(topic in watched.channels for topic in topics):
            message = await client.recv()
            if isinstance(message, str) and (op := json.loads(message))["op"] == "advertise":
                watched.channels.update({channel["topic"]: channel for channel in op["channels"]})
        subscriptions = {index: topic for index, topic in enumerate(topics, start=1)}
        channel_ids = {index: watched.channels[topic]["id"] for index, topic in subscriptions.items()}
        await _subscribe(client, channel_ids)
        watched.frames = {topic: [] for topic in topics}
        while any(len(frames) < PER_SUBSCRIPTION for frames in watched.frames.values()):
            message = await client.recv()
            if isinstance(message, bytes) and message[0] == MESSAGE_DATA:
                _opcode, subscription, log_time_ns = HEADER.unpack_from(message)
                watched.frames[subscriptions[subscription]].append((log_time_ns, message[HEADER.size :]))
            elif isinstance(message, str) and (unknown := UNKNOWN_CHANNEL.search(message)):
                # foxglove-sdk 0.30's race: a subscription that follows the channel's advertisement
                # within microseconds can find it not yet known (a status error): subscribe again
                channel = int(unknown.group(1))
                await _subscribe(client, {index: c for index, c in channel_ids.items() if c == channel})


def _watch_for(url: str, topics: list[str], timeout: float) -> Watched:
    """Watch ``url`` until each of ``topics`` brought :data:`PER_SUBSCRIPTION` messages; fail after ``timeout``."""
    watched = Watched()
    try:
        asyncio.run(asyncio.wait_for(_watch(url, topics, watched), timeout))
    except TimeoutError:
        missing = [t for t in topics if t not in watched.channels]
        counts = {t: len(f) for t, f in watched.frames.items()}
        raise AssertionError(f"within {timeout} s: never advertised {missing}; messages taken {counts}") from None
    return watched


def test_a_foxglove_client_sees_the_running_loop_live(tmp_path: Path) -> None:
    """The view starts once the loop runs: the planned path, published once when the drive's
    scenario started, can only reach its scene through the latched key's answer to a query."""
    with running_router() as endpoint, peer_session(endpoint) as watcher:
        commands = watcher.declare_subscriber(KEYS.drive_target_velocity, zenoh.handlers.RingChannel(1))
        loop = _Process(
            "up", "--loop", "--composed", "--scenario", "square", "--report", str(tmp_path), "--connect", endpoint
        )
        view: _Process | None = None
        try:
            wait_until(lambda: commands.try_recv() is not None, STARTUP_TIMEOUT_S, "the drive's first command")
            view = _Process("view", "--connect", endpoint, "--port", "0", "--log-level", "info")

            def announced() -> re.Match[str] | bool:
                return URL_LINE.search(view.output) or view.process.poll() is not None

            match = wait_until(announced, STARTUP_TIMEOUT_S, "the view's URL")
            assert isinstance(match, re.Match), f"the view exited:\n{view.output[-3000:]}"
            url, port = match.group(1), int(match.group(2))
            assert port > 0, "port 0: the line names the port it got"
            started_ns = time.time_ns()
            watched = _watch_for(url, list(SUBSCRIBED), WATCH_TIMEOUT_S)
            ok, view_status = call(watcher, KEYS.view_status)
            assert view.stop() == 0, view.output[-3000:]
            assert loop.stop(60) == 0, loop.output[-3000:]
        finally:
            if view is not None:
                view.kill()
            loop.kill()

    assert ok and view_status["service"] == "view" and view_status["url"] == url, view_status
    assert view_status["channels"] >= len(SUBSCRIBED) and view_status["messages"] > 0, view_status
    assert watched.subprotocol == "foxglove.sdk.v1"
    assert watched.server_info["op"] == "serverInfo" and watched.server_info["name"] == f"invent {KEYS.robot}"
    for topic, schema_name in SUBSCRIBED.items():
        channel = watched.channels[topic]
        if schema_name is None:
            assert channel["encoding"] == "json" and channel["schema"] == "", channel
        else:
            assert channel["schemaName"] == schema_name, channel
    assert watched.channels[KEYS.sim_body_pose]["schemaEncoding"] == "jsonschema"
    assert json.loads(watched.channels[WHEEL_SPEEDS_TOPIC]["schema"]) == WHEEL_SPEEDS_SCHEMA

    for topic, frames in watched.frames.items():
        log_times = [log_time_ns for log_time_ns, _payload in frames]
        assert log_times == sorted(log_times), f"{topic}: log times in order"
        assert started_ns - 60e9 < log_times[0] <= time.time_ns(), f"{topic}: log time is when the view took it"
    scene = SceneUpdate.FromString(watched.frames[SCENE_TOPIC][-1][1])
    [planned_path] = [entity for entity in scene.entities if entity.id == "planned_path"]
    assert len(planned_path.lines) == 1 and len(planned_path.lines[0].points) > 2, "the path published before the view"
    transforms = [payload for _log_time, payload in watched.frames[TRANSFORMS_TOPIC]]
    # /tf carries the robot's pose (world -> base_link) and, with each scan, the lidar's mount
    assert any(WORLD_FRAME.encode() in tf and ROBOT_FRAME.encode() in tf for tf in transforms), "world -> base_link"
    assert any(LIDAR_FRAME.encode() in tf for tf in transforms), "base_link -> base_scan"
    body_pose = decode(TimedDoubleSeq, watched.frames[KEYS.sim_body_pose][-1][1])
    assert len(body_pose.data) == 12, "a raw key's payload, as published"
    speeds = json.loads(watched.frames[WHEEL_SPEEDS_TOPIC][-1][1])
    assert set(speeds) == set(WHEEL_SPEEDS_SCHEMA["properties"])
    scan = FoxgloveLaserScan.FromString(watched.frames[SCAN_TOPIC][-1][1])
    assert scan.frame_id == LIDAR_FRAME and len(scan.ranges) == Config().lidar.rays, "the simulator's scan, drawn"
    status = json.loads(watched.frames[KEYS.status(Service.MOTOR)][-1][1])
    assert status["service"] == Service.MOTOR and isinstance(status["state"], str)


def _layout_paths(layout: dict[str, Any]) -> list[str]:
    """Every message path (``topic.field...``) of the layout's Plot and State Transitions panels."""
    return [
        path["value"]
        for panel, config in layout["configById"].items()
        if panel.split("!")[0] in ("Plot", "StateTransitions")
        for path in config["paths"]
    ]


def _panel(layout: dict[str, Any], kind: str) -> dict[str, Any]:
    (config,) = [config for panel, config in layout["configById"].items() if panel.split("!")[0] == kind]
    return config


def _split(path: str) -> tuple[str, list[str]]:
    """``invent/rh0/motor/torque.data[0]`` -> (``invent/rh0/motor/torque``, [``data``])."""
    topic, *fields = path.split(".")
    return topic, [re.sub(r"\[\d+\]$", "", name) for name in fields]


def test_the_layout_names_only_what_the_view_serves() -> None:
    layout = json.loads(LAYOUT.read_text())
    assert {"configById", "globalVariables", "userNodes", "playbackConfig", "layout"} <= set(layout)

    three_d = _panel(layout, "3D")
    assert three_d["followTf"] == ROBOT_FRAME and three_d["fixedFrame"] == WORLD_FRAME
    assert set(three_d["topics"]) == {
        SCENE_TOPIC,
        TRANSFORMS_TOPIC,
        ODOMETRY_TOPIC,
        LOCALIZATION_TOPIC,
        SCAN_TOPIC,
        MAP_TOPIC,
        COSTMAP_TOPIC,
    }

    served = served_topics(KEYS)
    paths = _layout_paths(layout)
    for path in paths:
        topic, fields = _split(path)
        assert topic in served, f"{path}: the view serves no {topic}"
        if topic == WHEEL_SPEEDS_TOPIC:
            schema: dict[str, Any] = WHEEL_SPEEDS_SCHEMA
            for name in fields:
                schema = schema["properties"][name]
        elif (message_type := schema_for_key(topic)) is not None:
            assert fields and fields[0] in {f.name for f in msgspec.structs.fields(message_type)}, path
    topics = {_split(path)[0] for path in paths}
    assert {WHEEL_SPEEDS_TOPIC, KEYS.motor_torque, KEYS.status(Service.MOTOR)} <= topics
    assert set(SCENE_TOPICS) <= served and KEYS.topic(Topic.SIM_BODY_POSE) in served
    assert f"{KEYS.status(Service.MOTOR)}.state" in paths, "the motor's state"
    assert f"{KEYS.drive_goal_feedback}.distance_remaining" in paths, "a goal's progress"
    assert f"{KEYS.drive_outcome}.outcome" in paths, "how a goal ended"

    def panels(node: Any) -> set[str]:
        return {node} if isinstance(node, str) else panels(node["first"]) | panels(node["second"])

    assert panels(layout["layout"]) == set(layout["configById"]), "every configured panel is laid out"


async def _advertised(url: str) -> set[str]:
    """The topics a server advertises to a new client at once."""
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=10, close_timeout=1) as client:
        assert json.loads(await client.recv())["op"] == "serverInfo"
        return {channel["topic"] for channel in json.loads(await client.recv())["channels"]}


def test_each_view_serves_only_its_own_channels() -> None:
    """Two views in one process (a composed run, a test) and a channel of foxglove's default
    context: each server advertises its own view's channels and nothing else."""
    contexts = [foxglove.Context(), foxglove.Context()]
    views = [FoxgloveChannels(context) for context in contexts]
    views[0].write_sample(KEYS.sim_body_pose, b'{"tm":{"sec":0,"nsec":0},"data":[]}', time.time_ns())
    views[1].write_foxglove(TRANSFORMS_TOPIC, FrameTransforms(transforms=[]), 0, time.time_ns())
    views[1].write_sample(KEYS.sim_body_pose, b"{}", time.time_ns())
    stray = foxglove.Channel("/default_context", message_encoding="json")
    servers = [foxglove.start_server(host="127.0.0.1", port=0, context=context) for context in contexts]
    try:
        first, second = (
            asyncio.run(asyncio.wait_for(_advertised(f"ws://127.0.0.1:{server.port}"), 20)) for server in servers
        )
    finally:
        for server in servers:
            server.stop()
        for view in views:
            view.close()
        stray.close()
    assert first == {KEYS.sim_body_pose}
    assert second == {KEYS.sim_body_pose, TRANSFORMS_TOPIC}


def test_a_port_taken_is_an_error_not_a_hang(session) -> None:
    port = free_port()
    taken = foxglove.start_server(host="127.0.0.1", port=port, context=foxglove.Context())
    try:
        code = run_view(session, KEYS, Config(), threading.Event(), "127.0.0.1", port)
    finally:
        taken.stop()
    assert code == ExitStatus.FAILURE


def test_a_view_behind_a_flood_stops_at_once_on_sigint() -> None:
    """A loop that publishes faster than the view takes (a lockstep run on a busy machine) keeps
    samples waiting in the view's subscription: on SIGINT it stops at once, not once they are taken."""
    pose = TimedDoubleSeq(
        tm=Time.from_nanoseconds(0), data=[0.0, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    )
    flooding = threading.Event()
    flooder_thread: threading.Thread | None = None
    published = [0]
    with running_router() as endpoint, peer_session(endpoint) as flooder:
        view = _Process("view", "--connect", endpoint, "--port", "0", "--log-level", "info")
        try:
            wait_until(lambda: URL_LINE.search(view.output), STARTUP_TIMEOUT_S, "the view's URL")
            publisher = flooder.declare_publisher(KEYS.sim_body_pose)
            wait_until(lambda: publisher.matching_status.matching, what="the view's subscription")

            def flood() -> None:
                while flooding.is_set():
                    published[0] += 1
                    stamped = msgspec.structs.replace(pose, tm=Time.from_nanoseconds(published[0]))
                    publisher.put(msgspec.json.encode(stamped))

            flooding.set()
            flooder_thread = threading.Thread(target=flood, daemon=True)
            flooder_thread.start()
            wait_until(lambda: published[0] > FLOOD_SAMPLES, what=f"{FLOOD_SAMPLES} samples flooded")
            stopping = time.monotonic()
            code = view.stop(timeout=FLOOD_STOP_S * 4)
            stopped_in = time.monotonic() - stopping
        finally:
            flooding.clear()
            if flooder_thread is not None:  # done putting before its session closes
                flooder_thread.join(5)
            view.kill()
    assert code == 0, view.output[-3000:]
    served = re.search(r"served (\d+) messages", view.output)
    assert served and 0 < int(served.group(1)), view.output[-3000:]
    assert stopped_in < FLOOD_STOP_S, f"stopped {stopped_in:.1f} s after SIGINT, the flood still coming"


def test_only_clients_offering_the_current_subprotocol_are_served() -> None:
    """What the README says of clients: ``foxglove.sdk.v1`` is served; a client offering only
    ``foxglove.websocket.v1`` (@foxglove/ws-protocol 0.8.0, older Lichtblick) gets HTTP 400."""
    server = foxglove.start_server(host="127.0.0.1", port=0, context=foxglove.Context())

    async def offer(subprotocols: list[str]) -> str | int:
        try:
            async with websockets.connect(
                f"ws://127.0.0.1:{server.port}", subprotocols=subprotocols, open_timeout=10
            ) as client:
                return str(client.subprotocol)
        except websockets.InvalidStatus as refused:
            return refused.response.status_code

    try:
        served = asyncio.run(offer(["foxglove.sdk.v1"]))
        refused = asyncio.run(offer(["foxglove.websocket.v1"]))
    finally:
        server.stop()
    assert served == "foxglove.sdk.v1"
    assert refused == 400


def test_hand_fed_scans_are_drawn_in_the_lidar_frame_and_a_malformed_one_is_dropped_and_counted() -> None:
    """A real view on a real router, fed ``sim/scan`` by hand (as the simulator publishes it): a
    Foxglove client gets each scan as a ``foxglove.LaserScan`` in ``base_scan`` and the transform
    that puts that frame on ``base_link``; malformed scans between them are dropped and counted
    in the view's status, and the view serves on."""
    good = LaserScan(
        tm=Time.from_nanoseconds(0),
        angle_min=-math.pi,
        angle_increment=2 * math.pi / 360,
        range_min=0.12,
        range_max=3.5,
        ranges=[None if ray % 3 else 1.0 + ray / 1000 for ray in range(360)],
    )
    malformed = [b"{", encode(good).replace(b"[null,", b"[-1.0,", 1)]
    feeding = threading.Event()
    fed = [0]
    feeder: threading.Thread | None = None
    with running_router() as endpoint, peer_session(endpoint) as session:
        view = _Process("view", "--connect", endpoint, "--port", "0", "--log-level", "info")
        try:
            match = wait_until(lambda: URL_LINE.search(view.output), STARTUP_TIMEOUT_S, "the view's URL")
            publisher = session.declare_publisher(KEYS.sim_scan)
            wait_until(lambda: publisher.matching_status.matching, what="the view's subscription")

            def feed() -> None:
                while feeding.is_set():
                    fed[0] += 1
                    stamped = msgspec.structs.replace(good, tm=Time.from_nanoseconds(fed[0] * 100_000_000))
                    publisher.put(malformed[fed[0] % 2] if fed[0] % 5 == 0 else encode(stamped))
                    time.sleep(0.05)

            feeding.set()
            feeder = threading.Thread(target=feed, daemon=True)
            feeder.start()
            watched = _watch_for(match.group(1), [SCAN_TOPIC, TRANSFORMS_TOPIC], WATCH_TIMEOUT_S)

            def counted() -> dict[str, Any] | None:
                ok, status = call(session, KEYS.view_status)
                assert ok, status
                return status if status["bad_input"]["by_key"].get(KEYS.sim_scan, {}).get("count", 0) >= 2 else None

            view_status = wait_until(counted, WATCH_TIMEOUT_S, "two malformed scans counted")
        finally:
            feeding.clear()
            if feeder is not None:
                feeder.join(5)
            code = view.stop()
    assert code == 0, view.output[-3000:]
    assert watched.channels[SCAN_TOPIC]["schemaName"] == "foxglove.LaserScan"
    for _log_time, payload in watched.frames[SCAN_TOPIC]:
        scan = FoxgloveLaserScan.FromString(payload)
        assert scan.frame_id == LIDAR_FRAME and len(scan.ranges) == 360
        assert list(scan.ranges) == good.ranges_or_inf()
        assert (scan.start_angle, scan.end_angle) == pytest.approx((-math.pi, math.pi - 2 * math.pi / 360))
    mounts = [
        FrameTransformsProto.FromString(payload).transforms[0] for _t, payload in watched.frames[TRANSFORMS_TOPIC]
    ]
    assert {(t.parent_frame_id, t.child_frame_id) for t in mounts} == {(ROBOT_FRAME, LIDAR_FRAME)}
    assert mounts[0].translation.z == Config().lidar.z, "at the [lidar] mount"
    assert view_status["bad_input"]["total"] == view_status["bad_input"]["by_key"][KEYS.sim_scan]["count"]
    assert view.process.returncode == 0 and "Traceback" not in view.output, "served on, stopped cleanly"
