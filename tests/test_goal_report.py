"""What a goal-mode run's recording and report say of its goals (docs/recording.md, report.json's
``goals``): :func:`services.recording.goal_report.goal_results` from sequences of GoalTarget,
GoalFeedback and ScenarioOutcome and the ground truth, the summary's lines, and ``run.mcap`` made of
a goal-mode run's journals as ``invent up`` makes it, read back into ``report.json`` as ``invent
report run.mcap`` does (no zenoh: the journals are written here)."""

from __future__ import annotations

import json
import math

import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import RunSummary, Time
from services.config import RecordConfig, load_config
from services.planar import Pose
from services.recording.goal_report import goal_lines, goal_results
from services.recording.mcap_files import read_messages
from services.recording.record import write_run_recording
from services.recording.report import loop_health, summary
from services.recording.run_report import write_run_report
from services.recording.scene import SCENE_TOPIC
from services.runtime.journal import Journal, journal_path
from tests.test_goal_scene import S, body_pose, feedback, outcome, target

MS = 1_000_000
KEYS = Keys("rh0")
PUBLISHED_NS = 1_800_000_000 * 10**9


def _straight(start_s: float, end_s: float, x0: float, x1: float, theta: float = 0.0) -> list[tuple[float, Pose]]:
    """Ground truth every 20 ms, from x0 to x1 along y = 0."""
    steps = round((end_s - start_s) / 0.02)
    return [
        (start_s + 0.02 * i, Pose(x0 + (x1 - x0) * i / steps, 0.0, theta if i == steps else 0.0))
        for i in range(steps + 1)
    ]


def test_no_goals_no_entries():
    assert goal_results([], [], [outcome(S, "", "completed")], _straight(0, 1, 0, 1)) == []
    assert goal_lines([]) == []


def test_each_goal_has_its_pose_outcome_reason_times_feedback_and_what_the_ground_truth_did():
    truth = _straight(0.0, 2.0, 0.0, 1.0) + _straight(2.02, 3.0, 1.0, 1.0, theta=1.57)[1:]
    goals = goal_results(
        [target(0, "g1", 1.0, 0.0, 1.6, tolerance=0.05)],
        [feedback(500 * MS, "g1", 0.75), feedback(1000 * MS, "g1", 0.5), feedback(1000 * MS, "other", 9.0)],
        [outcome(3 * S, "g1", "completed", elapsed_s=3.0)],
        truth,
    )
    (goal,) = goals
    assert goal["id"] == "g1" and goal["pose"] == {"x": 1.0, "y": 0.0, "theta": 1.6} and goal["frame"] == "map"
    assert (goal["position_tolerance"], goal["heading_tolerance"], goal["time_limit_s"]) == (0.05, 0.1, None)
    assert (goal["started_s"], goal["ended_s"], goal["elapsed_s"]) == (0.0, 3.0, 3.0)
    assert (goal["outcome"], goal["reason"]) == ("completed", "")
    assert goal["feedbacks"] == 2, "another goal's feedback is not this one's"
    assert goal["last_feedback"] == {
        "state": "executing",
        "distance_remaining_m": 0.5,
        "elapsed_s": 1.0,
        "estimated_remaining_s": 1.0,
    }
    truth_part = goal["ground_truth"]
    assert truth_part["start"] == {"x": 0.0, "y": 0.0, "theta": 0.0}
    assert truth_part["end"] == {"x": 1.0, "y": 0.0, "theta": 1.57}
    assert truth_part["driven_m"] == pytest.approx(1.0)
    assert truth_part["path_error_max_m"] == pytest.approx(0.0, abs=1e-12)
    assert truth_part["position_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert truth_part["heading_error_rad"] == pytest.approx(0.03)
    assert truth_part["within_tolerance"]


def test_a_preempted_goal_ends_canceled_and_the_next_one_is_its_own():
    truth = _straight(0.0, 4.0, 0.0, 2.0)
    goals = goal_results(
        [target(0, "g1", 3.0, 0.0, None), target(2 * S, "g2", 2.0, 0.0, None)],
        [],
        [outcome(2 * S, "g1", "canceled", "preempted by goal 'g2'", 2.0), outcome(4 * S, "g2", "completed", "", 2.0)],
        truth,
    )
    assert [(g["id"], g["outcome"], g["reason"]) for g in goals] == [
        ("g1", "canceled", "preempted by goal 'g2'"),
        ("g2", "completed", ""),
    ]
    first, second = (g["ground_truth"] for g in goals)
    assert first["end"]["x"] == pytest.approx(1.0) and first["position_error_m"] == pytest.approx(2.0)
    assert not first["within_tolerance"] and first["heading_error_rad"] is None
    assert second["start"]["x"] == pytest.approx(1.0) and second["driven_m"] == pytest.approx(1.0)
    assert second["within_tolerance"]


def test_an_id_used_again_a_goal_still_running_and_an_outcome_of_a_goal_never_started():
    truth = _straight(0.0, 5.0, 0.0, 1.0)
    goals = goal_results(
        [target(0, "g1", 1.0, 0.0), target(2 * S, "g1", 2.0, 0.0), target(4 * S, "late", 5.0, 5.0)],
        [feedback(4500 * MS, "late", 6.0)],
        [outcome(1 * S, "g1", "aborted", "bumped", 1.0), outcome(3 * S, "g1"), outcome(3500 * MS, "gone", "canceled")],
        truth,
    )
    assert [(g["id"], g["outcome"], g["started_s"], g["ended_s"]) for g in goals] == [
        ("g1", "aborted", 0.0, 1.0),
        ("g1", "completed", 2.0, 3.0),
        ("gone", "canceled", None, 3.5),
        ("late", None, 4.0, None),
    ]
    gone, late = goals[2], goals[3]
    assert gone["pose"] is None and gone["ground_truth"] is None
    assert late["ground_truth"]["end"]["x"] == pytest.approx(1.0), "the last pose recorded"
    assert late["feedbacks"] == 1 and late["last_feedback"]["distance_remaining_m"] == 6.0
    lines = goal_lines(goals)
    assert lines[0] == "goals: 4 (aborted 1, completed 1, canceled 1, running at the end 1)"
    assert lines[1].startswith("  goal g1 to (1.000, 0.000, 90.0 deg): aborted after 1.00 s (bumped); ground truth ")
    assert lines[3] == "  goal gone: canceled after 1.00 s"
    assert lines[4].startswith("  goal late to (5.000, 5.000, 90.0 deg): still running when the recording ended")


def test_the_summary_lists_at_most_ten_goals():
    targets = [target(i * S, f"g{i}", float(i), 0.0) for i in range(12)]
    outcomes = [outcome(i * S + 500 * MS, f"g{i}", elapsed_s=0.5) for i in range(12)]
    lines = goal_lines(goal_results(targets, [], outcomes, []))
    assert lines[0] == "goals: 12 (completed 12)" and len(lines) == 12
    assert lines[-1] == "  ... and 2 more goals (report.json: goals)"


EVENTS = st.lists(
    st.tuples(
        st.sampled_from(["target", "feedback", "outcome"]),
        st.integers(0, 10 * S),
        st.sampled_from(["g1", "g2", "g3", ""]),
        st.sampled_from(["completed", "aborted", "timed_out", "canceled"]),
    ),
    max_size=40,
)


@settings(max_examples=200, deadline=None)
@given(EVENTS)
def test_any_goal_events_give_one_entry_per_start_and_per_unmatched_outcome(events):
    targets = [target(t, i or "g0", 1.0, 1.0) for kind, t, i, _w in events if kind == "target"]
    feedbacks = [feedback(t, i, 1.0) for kind, t, i, _w in events if kind == "feedback"]
    outcomes = [outcome(t, i, w) for kind, t, i, w in events if kind == "outcome"]
    goals = goal_results(targets, feedbacks, outcomes, _straight(0.0, 10.0, 0.0, 1.0))
    ended = [g for g in goals if g["outcome"] is not None]
    assert len([g for g in goals if g["pose"] is not None]) <= len(targets)
    assert len(ended) == len([o for o in outcomes if o.goal_id]), "every goal outcome is some goal's, once"
    assert sum(g["feedbacks"] for g in goals) <= len(feedbacks)
    assert all(goal_lines(goals)[0].startswith(f"goals: {len(goals)} (") for _ in goals[:1])


def _goal_mode_journals(journals) -> None:
    """Four seconds of a goal-mode run as its processes journal it: the sim's ground truth; the
    drive's goals (g1 preempted by g2 at 1 s, g2 completed at 3 s), feedback, outcomes, and a goal
    no drive publishes (a tolerance of 0: someone's bad input, kept in the recording as the evidence
    but neither drawn nor reported); up's summary."""
    journals.mkdir()
    sim = Journal(journal_path(journals, str(Service.SIM)))
    for step in range(201):
        x = min(step * 0.01, 1.5)
        sim.write(KEYS.sim_body_pose, encode(body_pose(step * 20 * MS, x, 0.0)), PUBLISHED_NS + step * 20 * MS)
    sim.close()
    drive = Journal(journal_path(journals, str(Service.DRIVE)))
    published = [
        (0, KEYS.drive_goal, target(0, "g1", 3.0, 0.0, None)),
        (200 * MS, KEYS.drive_goal_feedback, feedback(200 * MS, "g1", 2.8)),
        (500 * MS, KEYS.drive_goal, target(500 * MS, "bad", 1.0, 1.0, tolerance=0.0)),  # no drive's: not a goal
        (1000 * MS, KEYS.drive_goal, target(S, "g2", 1.5, 0.0, 0.0)),
        (1000 * MS + 1, KEYS.drive_outcome, outcome(S, "g1", "canceled", "preempted by goal 'g2'", 1.0)),
        (1200 * MS, KEYS.drive_goal_feedback, feedback(1200 * MS, "g2", 0.3)),
        (3000 * MS, KEYS.drive_outcome, outcome(3 * S, "g2", "completed", "", 2.0)),
    ]
    for at_ns, key, message in published:
        drive.write(key, encode(message), PUBLISHED_NS + at_ns + 1)
    drive.close()
    up = Journal(journal_path(journals, "up"))
    run = RunSummary(Time(4, 0), "goals", "lockstep", False, 2.0, 4000, loop_health(None, {}))
    up.write(KEYS.run_summary, encode(run), PUBLISHED_NS + 4 * S)
    up.close()


def test_a_goal_mode_runs_recording_holds_its_goals_with_their_schemas_and_its_report_says_how_each_ended(tmp_path):
    _goal_mode_journals(tmp_path / "journals")
    output = tmp_path / "run.mcap"
    config = load_config(None, {})
    write_run_recording(tmp_path / "journals", output, config)

    messages = read_messages(output).messages
    schemas = {m.topic: m.schema_name for m in messages}
    assert schemas[KEYS.drive_goal] == "GoalTarget"
    assert schemas[KEYS.drive_goal_feedback] == "GoalFeedback"
    assert schemas[KEYS.drive_outcome] == "ScenarioOutcome"
    assert [json.loads(m.data)["id"] for m in messages if m.topic == KEYS.drive_goal] == ["g1", "bad", "g2"]
    assert [json.loads(m.data)["goal_id"] for m in messages if m.topic == KEYS.drive_outcome] == ["g1", "g2"]
    scene = [SceneUpdate.FromString(m.data) for m in messages if m.topic == SCENE_TOPIC]
    labels = [t.text for update in scene for e in update.entities if e.id == "goal" for t in e.texts]
    assert "g2 completed after 2.0 s" in labels and any(label.startswith("g1 executing") for label in labels)
    ended = [t.text for update in scene for e in update.entities if e.id == "goals_ended" for t in e.texts]
    assert "g1: canceled" in ended

    report, report_path, plots = write_run_report(output, tmp_path, config)
    assert json.loads(report_path.read_text()) == json.loads(json.dumps(report))
    assert report["scenario"] == "goals" and report["path_error"] is None, "no one planned path in goal mode"
    assert report["outcome"]["goal_id"] == "g2" and report["outcome"]["outcome"] == "completed"
    g1, g2 = report["goals"]
    assert (g1["id"], g1["outcome"], g1["reason"], g1["started_s"], g1["ended_s"]) == (
        "g1",
        "canceled",
        "preempted by goal 'g2'",
        0.0,
        1.0,
    )
    assert (g2["id"], g2["outcome"], g2["pose"]) == ("g2", "completed", {"x": 1.5, "y": 0.0, "theta": 0.0})
    assert (
        g2["ground_truth"]["position_error_m"] == pytest.approx(0.0, abs=1e-9)
        and g2["ground_truth"]["within_tolerance"]
    )
    assert g2["ground_truth"]["driven_m"] == pytest.approx(1.0) and g2["ground_truth"]["start"]["x"] == 0.5
    assert all(plot.exists() for plot in plots)
    text = summary(report)
    assert "outcome: completed" in text and "goals: 2 (canceled 1, completed 1)" in text
    assert (
        "  goal g1 to (3.000, 0.000): canceled after 1.00 s (preempted by goal 'g2'); ground truth 250.0 cm off" in text
    )


def test_a_stopped_recording_keeps_every_goal_and_its_outcome(tmp_path):
    """record.max_size reached: the goals (``drive/goal``) stay, as the outcomes that name them do."""
    _goal_mode_journals(tmp_path / "journals")
    output = tmp_path / "run.mcap"
    written = write_run_recording(
        tmp_path / "journals", output, load_config(None, {}), (), RecordConfig(max_size=0.001)
    )
    assert written.stopped is not None
    messages = read_messages(output).messages
    assert len([m for m in messages if m.topic == KEYS.drive_goal]) == 3
    assert len([m for m in messages if m.topic == KEYS.drive_outcome]) == 2
    assert math.isfinite(written.stopped["stopped_at_s"])
