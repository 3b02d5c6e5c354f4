"""``invent view`` without a loop: the layout names only what the view serves, each view serves only its
own channels, a port taken is an error, a view behind a flood stops at once on SIGINT, only clients
offering the current subprotocol are served, hand-fed scans are drawn in the lidar's frame and a
malformed one is dropped and counted (tests/test_view.py: a real client on the view of a real loop).
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import threading
import time
from typing import Any

import foxglove
import msgspec
import pytest
import websockets
from foxglove.messages import FrameTransforms
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms as FrameTransformsProto
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan as FoxgloveLaserScan

from schemas.codec import encode
from schemas.keys import Service, schema_for_key
from schemas.messages import LaserScan, Time, TimedDoubleSeq
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
from tests.harness import call, free_port, peer_session, running_router, wait_until
from tests.test_view import (
    FLOOD_SAMPLES,
    FLOOD_STOP_S,
    KEYS,
    LAYOUT,
    SCENE_TOPICS,
    STARTUP_TIMEOUT_S,
    SUBPROTOCOLS,
    URL_LINE,
    WATCH_TIMEOUT_S,
    _Process,
    _watch_for,
    served_topics,
)

pytestmark = pytest.mark.slow


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
