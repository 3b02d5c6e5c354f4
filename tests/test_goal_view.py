"""Goals in a real ``invent view`` and a real ``invent record``, fed by hand over a real router (no
drive: this test's session publishes on ``drive/goal``, ``drive/goal/feedback`` and
``drive/outcome`` what a goal-mode drive publishes, between the ground truth's samples): a
Foxglove client sees the goals drawn in ``/scene`` and the goal keys on their own channels with
their message types' schemas; the recording holds the same, and ``invent report`` says how each
goal ended; a goal no drive publishes is dropped and counted by the view, kept undrawn by the
recorder. One run of both processes, shared by the tests of this module."""

from __future__ import annotations

import asyncio
import json
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

import pytest
import websockets
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from schemas.codec import encode
from schemas.keys import Keys
from schemas.messages import RunSummary, Time
from services.recording.mcap_files import read_messages
from services.recording.report import loop_health
from services.recording.scene import SCENE_TOPIC
from tests.harness import InventProcess, call, peer_session, run_invent, running_router, wait_until
from tests.test_goal_scene import body_pose, feedback, outcome, target
from tests.test_view import HEADER, MESSAGE_DATA, STARTUP_TIMEOUT_S, SUBPROTOCOLS, UNKNOWN_CHANNEL, URL_LINE, _Process

pytestmark = pytest.mark.slow

KEYS = Keys()
STEP_NS = 100_000_000
"""Simulation time between two ground-truth samples fed (the scene updates every 5)."""
STEP_WALL_S = 0.02
WATCH_TIMEOUT_S = 60.0
GOAL_KEYS = {
    KEYS.drive_goal: "GoalTarget",
    KEYS.drive_goal_feedback: "GoalFeedback",
    KEYS.drive_outcome: "ScenarioOutcome",
}
WANTED = {SCENE_TOPIC, *GOAL_KEYS}


def _script(first: int) -> dict[int, list[tuple[str, bytes]]]:
    """What the drive would publish, by feeding step from ``first``: g1 (no heading) starts, a goal
    no drive publishes (a tolerance of 0) comes, g2 preempts g1 (g1 ends canceled), g2 completes;
    feedback every other step while a goal runs; then up's run summary."""
    at = {step: [] for step in range(first, first + 26)}

    def stamp(step: int) -> int:
        return step * STEP_NS

    at[first].append((KEYS.drive_goal, encode(target(stamp(first), "g1", 3.0, 0.0, None))))
    at[first + 5].append((KEYS.drive_goal, encode(target(stamp(first + 5), "bad", 1.0, 1.0, tolerance=0.0))))
    at[first + 10].append((KEYS.drive_goal, encode(target(stamp(first + 10), "g2", 1.5, 0.5, 1.57))))
    at[first + 10].append(
        (KEYS.drive_outcome, encode(outcome(stamp(first + 10), "g1", "canceled", "preempted by goal 'g2'", 1.0)))
    )
    for step in range(first + 1, first + 20, 2):
        goal = "g1" if step < first + 10 else "g2"
        at[step].append((KEYS.drive_goal_feedback, encode(feedback(stamp(step), goal, 0.1 * (first + 20 - step)))))
    at[first + 20].append((KEYS.drive_outcome, encode(outcome(stamp(first + 20), "g2", "completed", "", 1.0))))
    summary = RunSummary(
        Time.from_nanoseconds(stamp(first + 25)), "goals", "lockstep", False, 1.0, 1, loop_health(None, {})
    )
    at[first + 25].append((KEYS.run_summary, encode(summary)))
    return at


@dataclass
class Seen:
    """What the Foxglove client saw."""

    channels: dict[str, dict[str, Any]] = field(default_factory=dict)
    frames: dict[str, list[bytes]] = field(default_factory=dict)

    def scenes(self) -> list[SceneUpdate]:
        return [SceneUpdate.FromString(payload) for payload in self.frames.get(SCENE_TOPIC, [])]


def _labels(scenes: list[SceneUpdate], entity_id: str) -> list[str]:
    return [
        text.text for scene in scenes for entity in scene.entities if entity.id == entity_id for text in entity.texts
    ]


def _done(seen: Seen) -> bool:
    return any(label.startswith("g2 completed") for label in _labels(seen.scenes(), "goal"))


class Watched(Protocol):
    """What a live view's client keeps: each advertised channel by topic, each wanted topic's messages."""

    channels: dict[str, dict[str, Any]]
    frames: dict[str, list[bytes]]


WatchedT = TypeVar("WatchedT", bound=Watched)


async def watch_view(url: str, seen: WatchedT, done: Callable[[WatchedT], bool], wanted: set[str]) -> None:
    """Subscribe to each ``wanted`` channel as it is advertised, and take its messages until ``done``."""
    async with websockets.connect(
        url, subprotocols=SUBPROTOCOLS, open_timeout=10, close_timeout=1, max_size=None
    ) as client:
        assert json.loads(await client.recv())["op"] == "serverInfo"
        subscriptions: dict[int, str] = {}
        channel_ids: dict[int, int] = {}
        while not done(seen):
            message = await client.recv()
            if isinstance(message, bytes) and message[0] == MESSAGE_DATA:
                _opcode, subscription, _log_time_ns = HEADER.unpack_from(message)
                seen.frames.setdefault(subscriptions[subscription], []).append(message[HEADER.size :])
            elif isinstance(message, str) and (op := json.loads(message))["op"] == "advertise":
                new = {}
                for channel in op["channels"]:
                    seen.channels[channel["topic"]] = channel
                    if channel["topic"] in wanted and channel["topic"] not in subscriptions.values():
                        index = len(subscriptions) + 1
                        subscriptions[index], new[index] = channel["topic"], channel["id"]
                channel_ids.update(new)
                if new:
                    entries = [{"id": index, "channelId": channel} for index, channel in new.items()]
                    await client.send(json.dumps({"op": "subscribe", "subscriptions": entries}))
            elif isinstance(message, str) and (unknown := UNKNOWN_CHANNEL.search(message)):
                again = [{"id": i, "channelId": c} for i, c in channel_ids.items() if c == int(unknown.group(1))]
                await client.send(json.dumps({"op": "subscribe", "subscriptions": again}))


@dataclass
class GoalRun:
    seen: Seen
    view_status: dict[str, Any]
    view_code: int
    view_output: str
    recording: Path
    record_code: int
    published: dict[str, list[bytes]]


@pytest.fixture(scope="module")
def goal_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GoalRun]:
    output = tmp_path_factory.mktemp("goal_view") / "goals.mcap"
    seen = Seen()
    published: dict[str, list[bytes]] = {}
    feeding = threading.Event()
    feeder: threading.Thread | None = None
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = InventProcess("record", "--connect", endpoint, "--output", str(output), drain=True)
        view: _Process | None = None
        try:
            publishers = {
                key: session.declare_publisher(key) for key in (KEYS.sim_body_pose, *GOAL_KEYS, KEYS.run_summary)
            }
            # the view starts once the recorder's subscription has matched, so the match is the recorder's
            # (a view started beside it may match first on a loaded machine, and the recorder miss goals)
            wait_until(
                lambda: publishers[KEYS.sim_body_pose].matching_status.matching, 30, "the recorder's subscription"
            )
            view = _Process("view", "--connect", endpoint, "--port", "0", "--log-level", "info")
            match = wait_until(lambda: URL_LINE.search(view.output), STARTUP_TIMEOUT_S, "the view's URL")

            def feed() -> None:
                step = 0
                script: dict[int, list[tuple[str, bytes]]] = {}
                while feeding.is_set():
                    publishers[KEYS.sim_body_pose].put(encode(body_pose(step * STEP_NS, 0.02 * step, 0.0)))
                    if not script and seen.frames.get(SCENE_TOPIC):  # the client sees the scene: the goals begin
                        script = _script(step + 1)
                    for key, payload in script.get(step, []):
                        publishers[key].put(payload)
                        published.setdefault(key, []).append(payload)
                    step += 1
                    time.sleep(STEP_WALL_S)  # a pace for the feed, not a wait for a condition

            feeding.set()
            feeder = threading.Thread(target=feed, daemon=True)
            feeder.start()
            asyncio.run(asyncio.wait_for(watch_view(match.group(1), seen, _done, WANTED), WATCH_TIMEOUT_S))
            wait_until(lambda: KEYS.run_summary in published, 30, "the script's end")

            def counted() -> dict[str, Any] | None:
                ok, status = call(session, KEYS.view_status)
                assert ok, status
                return status if status["bad_input"]["by_key"].get(KEYS.drive_goal) else None

            view_status = wait_until(counted, 30, "the bad goal counted")
        finally:
            feeding.clear()
            if feeder is not None:
                feeder.join(5)
            view_code = view.stop() if view is not None else -1
            record_code, _out, err = recorder.stop(30)
    assert record_code == 0, err[-3000:]
    assert view is not None
    yield GoalRun(seen, view_status, view_code, view.output, output, record_code, published)


def test_the_view_draws_the_goals_and_their_outcomes_and_serves_the_goal_keys_with_their_schemas(goal_run):
    seen = goal_run.seen
    for key, schema in GOAL_KEYS.items():
        assert seen.channels[key]["schemaName"] == schema and seen.channels[key]["schemaEncoding"] == "jsonschema"
    feedbacks = [json.loads(payload) for payload in seen.frames.get(KEYS.drive_goal_feedback, [])]
    assert feedbacks and {f["id"] for f in feedbacks} <= {"g1", "g2"}, "the feedback on its own channel"
    scenes = seen.scenes()
    labels = _labels(scenes, "goal")
    assert any(
        re.fullmatch(r"g1 executing: \d\.\d\d m to go, .* s elapsed, about .* s left", label) for label in labels
    )
    assert labels[-1] == "g2 completed after 1.0 s"
    final = scenes[-1]
    (goal,) = [entity for entity in final.entities if entity.id == "goal"]
    (arrow,) = goal.arrows
    assert (arrow.pose.position.x, arrow.pose.position.y) == (1.5, 0.5), "g2 at its pose"
    assert goal.lines[0].points, "its position tolerance"
    (path,) = [entity for entity in final.entities if entity.id == "goal_path"]
    assert len(path.lines) == 1 and len(path.lines[0].points) > 2, "the path driven to g2"
    assert "g1: canceled" in _labels([final], "goals_ended"), "the preempted goal stays, marked"
    assert not any("bad" in label for label in labels + _labels(scenes, "goals_ended")), "the bad goal is not drawn"


def test_the_view_drops_and_counts_a_goal_no_drive_publishes_and_serves_on(goal_run):
    by_key = goal_run.view_status["bad_input"]["by_key"]
    assert by_key[KEYS.drive_goal]["count"] == 1, by_key
    assert "position_tolerance" in by_key[KEYS.drive_goal]["last_reason"], by_key
    assert goal_run.view_code == 0 and "Traceback" not in goal_run.view_output


def test_the_recording_holds_the_goal_keys_as_published_with_their_schemas_and_the_goals_drawn(goal_run):
    messages = read_messages(goal_run.recording).messages
    for key, schema in GOAL_KEYS.items():
        recorded = [m for m in messages if m.topic == key]
        assert {m.schema_name for m in recorded} == {schema}
        assert [m.data for m in recorded] == goal_run.published[key], f"{key}: every sample, as published"
    assert [json.loads(m.data)["id"] for m in messages if m.topic == KEYS.drive_goal] == ["g1", "bad", "g2"]
    outcomes = [json.loads(m.data) for m in messages if m.topic == KEYS.drive_outcome]
    assert [(o["goal_id"], o["outcome"]) for o in outcomes] == [("g1", "canceled"), ("g2", "completed")]
    scenes = [SceneUpdate.FromString(m.data) for m in messages if m.topic == SCENE_TOPIC]
    assert "g2 completed after 1.0 s" in _labels(scenes, "goal") and "g1: canceled" in _labels(scenes, "goals_ended")


def test_invent_report_on_the_recording_says_how_each_goal_ended(goal_run, tmp_path):
    reported = run_invent("report", str(goal_run.recording), "--output-dir", str(tmp_path), timeout=60)
    assert reported.returncode == 0, reported.stderr[-3000:]
    assert "goals: 2 (canceled 1, completed 1)" in reported.stdout, reported.stdout
    assert "  goal g1 to (3.000, 0.000): canceled after 1.00 s (preempted by goal 'g2')" in reported.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert [(g["id"], g["outcome"], g["reason"]) for g in report["goals"]] == [
        ("g1", "canceled", "preempted by goal 'g2'"),
        ("g2", "completed", ""),
    ]
    g2 = report["goals"][1]
    assert g2["pose"] == {"x": 1.5, "y": 0.5, "theta": 1.57} and g2["feedbacks"] == 5
    assert report["outcome"] == {**report["outcome"], "goal_id": "g2", "outcome": "completed"}
