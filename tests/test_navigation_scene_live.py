"""The drive's navigation in Foxglove, live: a real ``invent view`` and ``invent record`` on a real
router, started after the map and a plan were published on latched keys (this test's session answers
their queries as a drive's latched publishers do), draw them (tests/test_navigation_scene.py: the
pure conversion and ``run.mcap``).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader

from schemas.codec import encode
from services.recording.navigation_scene import (
    COSTMAP_TOPIC,
    GRID_UNKNOWN,
    MAP_TOPIC,
)
from services.recording.scene import SCENE_TOPIC, WORLD_FRAME
from tests.harness import InventProcess, peer_session, running_router, wait_until
from tests.test_goal_view import watch_view
from tests.test_navigation_scene import GEOMETRY, KEYS, S, _cells, _costmap, _entity, _plan, body_pose, occupancy
from tests.test_view import STARTUP_TIMEOUT_S, URL_LINE, _Process

# --- a real view and a real recorder, started after the map and the plan were published ---


STEP_NS = 100_000_000
STEP_WALL_S = 0.02
WATCH_TIMEOUT_S = 60.0
PLAN_POINTS_LIVE = [(0.0, 0.0), (0.5, 0.0), (1.0, 0.5), (1.5, 1.5)]
WANTED = {MAP_TOPIC, COSTMAP_TOPIC, SCENE_TOPIC}


@dataclass
class Seen:
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    frames: dict[str, list[bytes]] = field(default_factory=dict)

    def plans(self) -> list[list[tuple[float, float]]]:
        return [
            [(p.x, p.y) for line in _entity(SceneUpdate.FromString(data), "plan").lines for p in line.points]
            for data in self.frames.get(SCENE_TOPIC, [])
        ]


@dataclass
class LiveRun:
    seen: Seen
    recording: Path
    view_code: int
    view_output: str
    map_payload: bytes
    plan_payload: bytes


class _Latched:
    """A drive's latched key, as its ``LatchedPublisher`` serves it: a publisher, and a queryable
    answering the last sample."""

    def __init__(self, session: zenoh.Session, key: str, payload: bytes) -> None:
        self.key = key
        self.last = payload
        self.publisher = session.declare_publisher(key)
        self.queryable = session.declare_queryable(key, self._answer)

    def _answer(self, query: zenoh.Query) -> None:
        query.reply(self.key, self.last)

    def put(self, payload: bytes) -> None:
        self.last = payload
        self.publisher.put(payload)

    def close(self) -> None:
        self.queryable.undeclare()
        self.publisher.undeclare()


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveRun]:
    output = tmp_path_factory.mktemp("navigation_view") / "navigation.mcap"
    seen = Seen()
    map_payload = encode(occupancy(0, GEOMETRY, _cells()))
    plan_payload = encode(_plan(0, PLAN_POINTS_LIVE))
    feeding = threading.Event()
    feeder: threading.Thread | None = None
    with running_router() as endpoint, peer_session(endpoint) as session:
        latched = [_Latched(session, KEYS.drive_map, map_payload), _Latched(session, KEYS.drive_plan, plan_payload)]
        for key in latched:
            key.put(key.last)  # published before anyone listens: only the queryables can bring them
        costmaps = session.declare_publisher(KEYS.drive_costmap)
        poses = session.declare_publisher(KEYS.sim_body_pose)
        recorder = InventProcess("record", "--connect", endpoint, "--output", str(output), drain=True)
        view: _Process | None = None
        try:
            wait_until(
                lambda: poses.matching_status.matching and costmaps.matching_status.matching,
                30,
                "the recorder's subscription",
            )
            view = _Process(
                "view", "--connect", endpoint, "--port", "0", "--log-level", "info"
            )  # after: no other match
            match = wait_until(lambda: URL_LINE.search(view.output), STARTUP_TIMEOUT_S, "the view's URL")

            def feed() -> None:
                step = 0
                while feeding.is_set():
                    poses.put(encode(body_pose(step * STEP_NS, 0.01 * step)))
                    if step % 10 == 0:
                        costmaps.put(encode(_costmap(step * STEP_NS, 40)))
                    step += 1
                    time.sleep(STEP_WALL_S)  # a pace for the feed, not a wait for a condition

            def drawn(seen: Seen) -> bool:
                return bool(seen.frames.get(MAP_TOPIC) and seen.frames.get(COSTMAP_TOPIC)) and (
                    PLAN_POINTS_LIVE in seen.plans()
                )

            feeding.set()
            feeder = threading.Thread(target=feed, daemon=True)
            feeder.start()
            url = match.group(1)
            asyncio.run(asyncio.wait_for(watch_view(url, seen, drawn, WANTED), WATCH_TIMEOUT_S))
            latched[1].put(encode(_plan(10 * S, [])))  # the goal ended
            asyncio.run(asyncio.wait_for(watch_view(url, seen, lambda s: s.plans()[-1] == [], WANTED), WATCH_TIMEOUT_S))
        finally:
            feeding.clear()
            if feeder is not None:
                feeder.join(5)
            view_code = view.stop() if view is not None else -1
            record_code, _out, err = recorder.stop(30)
            for key in latched:
                key.close()
    assert record_code == 0, err[-3000:]
    assert view is not None
    yield LiveRun(seen, output, view_code, view.output, map_payload, plan_payload)


@pytest.mark.slow
def test_a_map_and_a_plan_published_before_the_view_started_are_drawn_live(live_run):
    seen = live_run.seen
    for topic in (MAP_TOPIC, COSTMAP_TOPIC):
        assert seen.channels[topic]["schemaName"] == "foxglove.Grid"
    grid = Grid.FromString(seen.frames[MAP_TOPIC][-1])
    assert grid.frame_id == WORLD_FRAME and (grid.pose.position.x, grid.pose.position.y) == (-1.5, 2.25)
    expected = _cells()
    expected[2, 4] = GRID_UNKNOWN
    assert (np.frombuffer(grid.data, dtype=np.int8).reshape(GEOMETRY.shape) == expected).all()
    assert Grid.FromString(seen.frames[COSTMAP_TOPIC][-1]).column_count == 40
    assert PLAN_POINTS_LIVE in seen.plans() and seen.plans()[-1] == [], "drawn, then cleared by the empty plan"
    assert live_run.view_code == 0 and "Traceback" not in live_run.view_output


@pytest.mark.slow
def test_a_recorder_started_after_them_has_the_latched_map_and_plan_and_draws_them(live_run):
    with live_run.recording.open("rb") as file:
        recorded: dict[str, list[bytes]] = {}
        for _schema, channel, message in make_reader(file).iter_messages():
            recorded.setdefault(channel.topic, []).append(message.data)
    assert recorded[KEYS.drive_map] == [live_run.map_payload], "the latched answer, as published"
    assert recorded[KEYS.drive_plan][0] == live_run.plan_payload
    assert recorded[MAP_TOPIC] and recorded[COSTMAP_TOPIC] and recorded[KEYS.drive_costmap]
    plans = [
        [(p.x, p.y) for line in _entity(SceneUpdate.FromString(data), "plan").lines for p in line.points]
        for data in recorded[SCENE_TOPIC]
    ]
    assert PLAN_POINTS_LIVE in plans and plans[-1] == []
