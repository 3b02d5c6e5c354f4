"""services/recording/goal_scene.py through services/recording/scene.py: the drive's goals drawn in
Foxglove's 3D scene from sequences of ``drive/goal`` (GoalTarget), ``drive/goal/feedback``
(GoalFeedback) and ``drive/outcome`` (ScenarioOutcome with a ``goal_id``) and the ground truth, as
the live view and the recording draw them (pure: no zenoh, no server, no file). Every scene update
is read back through its protobuf encoding with Foxglove's own compiled schemas."""

from __future__ import annotations

import math
from typing import Any

import foxglove.messages
import msgspec
import pytest
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput, decode, encode
from schemas.keys import Keys
from schemas.messages import ScenarioOutcome, Time, TimedDoubleSeq, TimedPosition
from schemas.navigation import GoalFeedback, GoalTarget
from schemas.topics import Topic
from services.config import Config, load_config
from services.recording.goal_scene import ENDED_GOALS, OUTCOME_COLORS, RUNNING
from services.recording.record import SceneBuilder, Sink
from services.recording.scene import GOAL_PATH_POINTS, SCENE_PERIOD_NS, SCENE_TOPIC, WORLD_FRAME, Scene
from services.runtime.logs import BadInputCounter

CONFIG = Config()
MS = 1_000_000
S = 1_000_000_000


def _stamp(ns: int) -> Time:
    return Time.from_nanoseconds(ns)


def target(
    stamp_ns: int, goal_id: str, x: float, y: float, theta: float | None = 1.57, tolerance: float = 0.05
) -> GoalTarget:
    return GoalTarget(
        tm=_stamp(stamp_ns),
        id=goal_id,
        x=x,
        y=y,
        theta=theta,
        frame="map",
        position_tolerance=tolerance,
        heading_tolerance=0.1,
        time_limit_s=None,
    )


def feedback(stamp_ns: int, goal_id: str, distance: float, state: str = "executing") -> GoalFeedback:
    return GoalFeedback(
        tm=_stamp(stamp_ns),
        id=goal_id,
        state=state,  # type: ignore[arg-type]
        x=0.0,
        y=0.0,
        theta=0.0,
        distance_remaining=distance,
        elapsed_s=stamp_ns / S,
        estimated_remaining_s=2 * distance,
    )


def outcome(stamp_ns: int, goal_id: str, word: str = "completed", reason: str = "", elapsed_s: float = 1.0):
    return ScenarioOutcome(
        tm=_stamp(stamp_ns),
        scenario="goals",
        outcome=word,  # type: ignore[arg-type]
        reason=reason,
        iteration=0,
        elapsed_s=elapsed_s,
        goal_id=goal_id,
    )


def body_pose(stamp_ns: int, x: float, y: float = 0.0) -> TimedDoubleSeq:
    return TimedDoubleSeq(_stamp(stamp_ns), [x, y, 0.05, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])


def _scene_of(shown: list[tuple[str, Any]]) -> SceneUpdate | None:
    updates = [message for topic, message in shown if topic == SCENE_TOPIC]
    return SceneUpdate.FromString(updates[-1].encode()) if updates else None


def _entity(update: SceneUpdate, entity_id: str) -> Any:
    (entity,) = [entity for entity in update.entities if entity.id == entity_id]
    return entity


def _drive(scene: Scene, events: list[tuple[Topic, Any]]) -> SceneUpdate:
    """Feed ``events`` and return the scene update the next body pose brings."""
    for topic, message in events:
        assert scene.add(topic, message) == []
    latest = max(m.tm.to_nanoseconds() for _t, m in events)
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(latest + SCENE_PERIOD_NS, 0.0)))
    assert update is not None
    return update


def _rgb(color: Any) -> tuple[float, float, float]:
    return (round(color.r, 3), round(color.g, 3), round(color.b, 3))


def _expected_rgb(color: Any) -> tuple[float, float, float]:
    """A foxglove-sdk ``Color`` (no fields to read) as Foxglove decodes it."""
    return _rgb(Color.FromString(color.encode()))


def test_before_any_goal_the_goal_entities_are_there_and_empty():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(0, 0.0)))
    assert update is not None
    for entity_id in ("goal", "goal_path", "goals_ended"):
        entity = _entity(update, entity_id)
        assert entity.frame_id == WORLD_FRAME
        assert not (entity.arrows or entity.spheres or entity.lines or entity.texts), entity_id


def test_a_running_goal_is_an_arrow_at_its_pose_with_its_tolerances_and_its_feedback_in_the_label():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    assert _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(S - 10 * MS, 0.0))) is not None
    shown = scene.add(Topic.DRIVE_GOAL, target(S, "g1", 1.5, 0.5, 1.57, tolerance=0.05))
    assert shown == [], "drawn at the next scene update"
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(S + 20 * MS, 0.0)))
    assert update is not None, "a new goal brings a scene update at once, not at the next period"
    goal = _entity(update, "goal")
    (arrow,) = goal.arrows
    assert (arrow.pose.position.x, arrow.pose.position.y) == (1.5, 0.5)
    assert 2 * math.atan2(arrow.pose.orientation.z, arrow.pose.orientation.w) == pytest.approx(1.57)
    assert _rgb(arrow.color) == _expected_rgb(RUNNING)
    circle, wedge = goal.lines
    assert circle.type == LinePrimitive.LINE_LOOP
    radii = [math.hypot(p.x - 1.5, p.y - 0.5) for p in circle.points]
    assert radii == pytest.approx([0.05] * len(radii)), "the position tolerance"
    assert wedge.type == LinePrimitive.LINE_LIST and len(wedge.points) == 4
    edges = sorted(math.atan2(end.y - start.y, end.x - start.x) for start, end in zip(*[iter(wedge.points)] * 2))
    assert edges == pytest.approx([1.47, 1.67]), "the heading tolerance either side of the heading"
    (label,) = goal.texts
    assert label.text == "g1 started"

    scene.add(Topic.DRIVE_GOAL_FEEDBACK, feedback(S + 200 * MS, "g1", 1.23))
    later = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(S + SCENE_PERIOD_NS + 20 * MS, 0.5)))
    assert later is not None
    text = _entity(later, "goal").texts[0].text
    assert text.startswith("g1 executing: 1.23 m to go, 1.2 s elapsed, about 2.5 s left"), text


def test_a_goal_without_heading_is_a_sphere_with_its_circle_and_no_heading_wedge():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    update = _drive(scene, [(Topic.DRIVE_GOAL, target(0, "free", -1.0, 2.0, None, tolerance=0.2))])
    goal = _entity(update, "goal")
    assert not goal.arrows
    (sphere,) = goal.spheres
    assert (sphere.pose.position.x, sphere.pose.position.y) == (-1.0, 2.0)
    (circle,) = goal.lines
    assert max(math.hypot(p.x + 1.0, p.y - 2.0) for p in circle.points) == pytest.approx(0.2)


def test_the_path_driven_is_the_ground_truth_from_the_goals_start_to_its_outcome():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    for step in range(10):  # before the goal: the run's trail, not the goal's path
        scene.add(Topic.SIM_BODY_POSE, body_pose(step * 100 * MS, -0.5 + 0.05 * step))
    scene.add(Topic.DRIVE_GOAL, target(S, "g1", 1.0, 0.0, None))
    for step in range(11):
        scene.add(Topic.SIM_BODY_POSE, body_pose(S + step * 100 * MS, 0.1 * step))
    scene.add(Topic.DRIVE_OUTCOME, outcome(2 * S, "g1"))
    shown = scene.add(Topic.SIM_BODY_POSE, body_pose(2 * S + 100 * MS, 5.0))  # after it: not the goal's
    update = _scene_of(shown)
    assert update is not None, "an outcome brings a scene update at once"
    (path,) = _entity(update, "goal_path").lines
    xs = [point.x for point in path.points]
    assert xs[0] == 0.0 and xs[-1] == pytest.approx(1.0) and len(xs) == 11
    assert _rgb(path.color) == _expected_rgb(OUTCOME_COLORS["completed"])
    goal = _entity(update, "goal")
    assert _rgb(goal.spheres[0].color) == _expected_rgb(OUTCOME_COLORS["completed"])
    assert goal.texts[0].text == "g1 completed after 1.0 s"


def test_a_preempted_goal_stays_drawn_canceled_beside_the_new_one():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    update = _drive(
        scene,
        [
            (Topic.DRIVE_GOAL, target(0, "g1", 2.0, 0.0)),
            (Topic.DRIVE_GOAL_FEEDBACK, feedback(200 * MS, "g1", 1.5)),
            (Topic.DRIVE_GOAL, target(S, "g2", 0.0, 2.0)),  # the new goal first, then the old one's end
            (Topic.DRIVE_OUTCOME, outcome(S, "g1", "canceled", "preempted by goal 'g2'")),
            (Topic.DRIVE_GOAL_FEEDBACK, feedback(S + 200 * MS, "g1", 1.4)),  # a stale one: not drawn
        ],
    )
    goal = _entity(update, "goal")
    assert (goal.arrows[0].pose.position.x, goal.arrows[0].pose.position.y) == (0.0, 2.0)
    assert goal.texts[0].text == "g2 started"
    ended = _entity(update, "goals_ended")
    assert [(a.pose.position.x, a.pose.position.y) for a in ended.arrows] == [(2.0, 0.0)]
    assert [t.text for t in ended.texts] == ["g1: canceled"]
    assert _rgb(ended.arrows[0].color) == _expected_rgb(OUTCOME_COLORS["canceled"])
    assert not ended.lines, "an ended goal's tolerances are not drawn"


@pytest.mark.parametrize("word", ["aborted", "timed_out", "canceled"])
def test_a_goal_given_up_is_marked_with_its_outcome_and_reason(word):
    scene = Scene(CONFIG.robot, CONFIG.sim)
    reason = "bumped into 'crate' at (1.20, 0.00) " * 10
    update = _drive(
        scene, [(Topic.DRIVE_GOAL, target(0, "g7", 2.0, 0.0)), (Topic.DRIVE_OUTCOME, outcome(S, "g7", word, reason))]
    )
    goal = _entity(update, "goal")
    assert _rgb(goal.arrows[0].color) == _expected_rgb(OUTCOME_COLORS[word])
    text = goal.texts[0].text
    assert text.startswith(f"g7 {word} after 1.0 s: bumped into 'crate'") and text.endswith("…")
    assert len(text) < 200, "a long reason is cut"


def test_an_outcome_that_comes_before_its_goal_still_marks_it():
    """A recorder started mid-run asks both latched keys, and their answers come in no set order."""
    scene = Scene(CONFIG.robot, CONFIG.sim)
    update = _drive(
        scene, [(Topic.DRIVE_OUTCOME, outcome(3 * S, "g1", "completed")), (Topic.DRIVE_GOAL, target(S, "g1", 1.0, 0.0))]
    )
    assert _entity(update, "goal").texts[0].text == "g1 completed after 1.0 s"


def test_a_scenarios_outcome_and_another_goals_feedback_draw_nothing():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    scene.add(Topic.DRIVE_GOAL, target(0, "g1", 1.0, 0.0))
    assert not scene.goals.end(outcome(S, "", "completed")), "a scenario's outcome is no goal's"
    assert not scene.goals.end(outcome(S, "g9", "completed")), "a goal never seen"
    scene.add(Topic.DRIVE_GOAL_FEEDBACK, feedback(S, "g9", 3.0))
    update = _drive(scene, [(Topic.DRIVE_GOAL_FEEDBACK, feedback(S, "g9", 3.0))])
    assert _entity(update, "goal").texts[0].text == "g1 started"
    assert not _entity(update, "goals_ended").texts


def test_the_same_goal_twice_is_one_goal():
    """A latched key's answer beside its own sample (a view that joined as the goal started)."""
    scene = Scene(CONFIG.robot, CONFIG.sim)
    update = _drive(
        scene, [(Topic.DRIVE_GOAL, target(0, "g1", 1.0, 0.0)), (Topic.DRIVE_GOAL, target(0, "g1", 1.0, 0.0))]
    )
    assert not _entity(update, "goals_ended").arrows


@pytest.mark.parametrize(
    "wrong",
    [
        target(0, "g1", 1.0, 0.0, tolerance=0.0),
        msgspec.structs.replace(target(0, "g1", 1.0, 0.0), heading_tolerance=-0.1),
        msgspec.structs.replace(target(0, "g1", 1.0, 0.0), time_limit_s=0.0),
        target(0, "g" * 65, 1.0, 0.0),
    ],
    ids=["zero position tolerance", "negative heading tolerance", "zero time limit", "an id too long"],
)
def test_a_goal_the_drive_never_publishes_does_not_decode(wrong):
    with pytest.raises(BadInput):
        decode(GoalTarget, encode(wrong))


def test_the_live_view_drops_and_counts_a_bad_goal_and_a_recorder_keeps_it_undrawn():
    bad = encode(target(0, "g1", 1.0, 0.0, tolerance=0.0))
    keys = Keys()
    counter = BadInputCounter("view")
    samples: list[str] = []
    view = SceneBuilder(CONFIG, Sink(lambda key, *_: samples.append(key), lambda *_: None), bad_input=counter)
    view.take(keys.drive_goal, bad, 0)
    assert samples == [] and counter.status().by_key[keys.drive_goal].count == 1
    recorder = SceneBuilder(CONFIG, Sink(lambda key, *_: samples.append(key), lambda *_: None))
    recorder.take(keys.drive_goal, bad, 0)
    assert samples == [keys.drive_goal], "the recording is the evidence"


def test_a_fleets_goals_are_each_robots_own_entities():
    fleet = [load_config(overrides={"robot.name": name}) for name in ("rh0", "rh1")]
    shown: list[tuple[str, Any]] = []
    builder = SceneBuilder(
        fleet[0], Sink(lambda *_: None, lambda topic, message, *_: shown.append((topic, message))), fleet
    )
    builder.take(Keys("rh1").drive_goal, encode(target(0, "g1", 1.0, 1.0)), 0)
    builder.take(Keys("rh1").sim_body_pose, encode(body_pose(MS, 0.0)), 0)
    update = _scene_of(shown)
    assert update is not None
    assert _entity(update, "rh1/goal").arrows and _entity(update, "rh1/goal").texts[0].text == "g1 started"
    assert {"rh1/goal_path", "rh1/goals_ended"} <= {entity.id for entity in update.entities}


GOAL_IDS = st.sampled_from(["g1", "g2", "g3"])
EVENT = st.one_of(
    st.builds(
        lambda t, i, x, y, th: (Topic.DRIVE_GOAL, target(t, i, x, y, th)),
        st.integers(0, 20 * S),
        GOAL_IDS,
        st.floats(-5, 5),
        st.floats(-5, 5),
        st.none() | st.floats(-math.pi, math.pi),
    ),
    st.builds(
        lambda t, i, d: (Topic.DRIVE_GOAL_FEEDBACK, feedback(t, i, d)),
        st.integers(0, 20 * S),
        GOAL_IDS,
        st.floats(0, 10),
    ),
    st.builds(
        lambda t, i, w: (Topic.DRIVE_OUTCOME, outcome(t, i, w)),
        st.integers(0, 20 * S),
        GOAL_IDS | st.just(""),
        st.sampled_from(["completed", "aborted", "timed_out", "canceled"]),
    ),
    st.builds(
        lambda t, x, y: (Topic.SIM_BODY_POSE, body_pose(t, x, y)),
        st.integers(0, 20 * S),
        st.floats(-5, 5),
        st.floats(-5, 5),
    ),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(EVENT, max_size=60))
def test_any_sequence_of_goal_events_draws_a_bounded_scene(events):
    """Goals, feedback and outcomes in any order, any stamps, ids used again: never an error,
    always the three goal entities, at most the ended goals kept, the path bounded."""
    scene = Scene(CONFIG.robot, CONFIG.sim)
    for topic, message in events:
        scene.add(topic, message)
    entities = scene.goals.entities(foxglove.messages.Timestamp(0, 0), WORLD_FRAME)
    update = SceneUpdate.FromString(foxglove.messages.SceneUpdate(entities=entities).encode())
    goal, path, ended = (_entity(update, entity_id) for entity_id in ("goal", "goal_path", "goals_ended"))
    started = [m for t, m in events if t is Topic.DRIVE_GOAL]
    assert len(goal.arrows) + len(goal.spheres) == (1 if started else 0)
    assert len(ended.texts) <= ENDED_GOALS
    assert all(len(line.points) <= GOAL_PATH_POINTS for line in path.lines)


def test_goals_add_a_bounded_cost_to_every_scene_update():
    """Two minutes around a circle with the trails full, the running goal's path full (its newest
    10 m) and every ended goal kept, ids of 64 characters: each update stays under 45 kB (about
    30 kB without goals: tests/test_scene.py)."""
    scene = Scene(CONFIG.robot, CONFIG.sim)
    for index in range(ENDED_GOALS + 1):
        goal_id = f"{index}".rjust(64, "g")
        scene.add(Topic.DRIVE_GOAL, target(index, goal_id, 50.0, 50.0))
        scene.add(Topic.DRIVE_OUTCOME, outcome(index, goal_id, "aborted", "x" * 500))
    running = "r" * 64
    scene.add(Topic.DRIVE_GOAL, target(ENDED_GOALS + 1, running, 50.0, 50.0))
    biggest = 0
    for stamp_ns in range(100 * MS, 120 * S, 20 * MS):
        angle = 0.3 * stamp_ns / S
        scene.add(Topic.DRIVE_GOAL_FEEDBACK, feedback(stamp_ns, running, 99.99))
        x, y = math.cos(angle), math.sin(angle)
        scene.add(Topic.ODOMETRY_POSE, TimedPosition(tm=_stamp(stamp_ns), id=[], x=x, y=y, theta=angle, error=[]))
        for topic, message in scene.add(Topic.SIM_BODY_POSE, body_pose(stamp_ns, x, y)):
            if topic == SCENE_TOPIC:
                biggest = max(biggest, len(message.encode()))
    assert len(scene.goals.current.path.points) == GOAL_PATH_POINTS, "the goal's path is full"
    assert len(scene.goals.ended) == ENDED_GOALS
    assert 35_000 < biggest < 45_000, "the trails and the goal's path full"
