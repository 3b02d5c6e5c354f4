"""The goals of a goal-mode run in its report (``report.json``'s ``goals``, the summary's goal
lines): each goal from ``drive/goal``, its feedback and its outcome, and what the ground truth did
meanwhile. Pure."""

from __future__ import annotations

import bisect
import itertools
import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

from schemas.messages import ScenarioOutcome
from schemas.navigation import GoalFeedback, GoalTarget
from services.drive.scenarios import distance_to_path
from services.planar import Pose, wrap_angle


def goal_results(
    targets: Sequence[GoalTarget],
    feedbacks: Sequence[GoalFeedback],
    outcomes: Sequence[ScenarioOutcome],
    ground_truth: Sequence[tuple[float, Pose]],
) -> list[dict[str, Any]]:
    """``report.json``'s ``goals``: each goal of a goal-mode run (docs/protocol.md section 7.3) in the
    order they started: what was asked (``drive/goal``), how it ended (its ``drive/outcome``, None
    while it still ran when the recording ended), its last feedback, and what the ground truth did
    meanwhile. A goal is matched to the first outcome of its id at or after its start (ids may be
    used again once a goal has ended); an outcome of a goal never seen starting (canceled before
    its first tick, or started before the recording) is a goal of its own, without a pose.
    Feedback is counted for the goal of its id running at its stamp. At one stamp a start comes
    before a feedback and an outcome (a goal may end at the tick it started: already there, or
    canceled)."""
    events: list[tuple[int, int, GoalTarget | GoalFeedback | ScenarioOutcome]] = [
        *((t.tm.to_nanoseconds(), 0, t) for t in targets),
        *((f.tm.to_nanoseconds(), 1, f) for f in feedbacks),
        *((o.tm.to_nanoseconds(), 2, o) for o in outcomes if o.goal_id),
    ]
    events.sort(key=lambda event: event[:2])
    goals: list[dict[str, Any]] = []
    running: dict[str, dict[str, Any]] = {}
    for _stamp, _order, event in events:
        if isinstance(event, ScenarioOutcome):
            goal = running.pop(event.goal_id, None)
            if goal is None:
                goal = _goal_entry(None, event.goal_id)
                goals.append(goal)
            goal.update(
                outcome=event.outcome, reason=event.reason, ended_s=event.tm.to_seconds(), elapsed_s=event.elapsed_s
            )
        elif isinstance(event, GoalTarget):
            if event.id in running and running[event.id]["target"] == event:
                continue  # the same start twice (a latched key's answer beside its sample)
            goal = running[event.id] = _goal_entry(event, event.id)
            goals.append(goal)
        elif (goal := running.get(event.id)) is not None:
            goal["feedbacks"] += 1
            goal["last_feedback"] = {
                "state": event.state,
                "distance_remaining_m": event.distance_remaining,
                "elapsed_s": event.elapsed_s,
                "estimated_remaining_s": event.estimated_remaining_s,
            }
    times = [t for t, _pose in ground_truth]
    for goal in goals:
        target = goal.pop("target")
        goal["ground_truth"] = None if target is None else _goal_ground_truth(goal, target, ground_truth, times)
    return goals


def _goal_entry(target: GoalTarget | None, goal_id: str) -> dict[str, Any]:
    return {
        "id": goal_id,
        "target": target,
        "pose": None if target is None else {"x": target.x, "y": target.y, "theta": target.theta},
        "frame": None if target is None else target.frame,
        "position_tolerance": None if target is None else target.position_tolerance,
        "heading_tolerance": None if target is None else target.heading_tolerance,
        "time_limit_s": None if target is None else target.time_limit_s,
        "started_s": None if target is None else target.tm.to_seconds(),
        "outcome": None,
        "reason": "",
        "ended_s": None,
        "elapsed_s": None,
        "feedbacks": 0,
        "last_feedback": None,
    }


def _goal_ground_truth(
    goal: dict[str, Any], target: GoalTarget, ground_truth: Sequence[tuple[float, Pose]], times: list[float]
) -> dict[str, Any] | None:
    """Where the robot truly was when the goal started and when it ended (the last pose recorded if
    it never did), how far it drove between, how far that path strayed from the straight line the
    drive follows, and how far from the goal it ended."""
    start_s, end_s = goal["started_s"], goal["ended_s"]
    first = max(bisect.bisect_right(times, start_s) - 1, 0)
    last = len(times) if end_s is None else bisect.bisect_right(times, end_s)
    driven = [pose for _t, pose in ground_truth[first:last]]
    if not driven:
        return None
    start, end = driven[0], driven[-1]
    heading_error = None if target.theta is None else abs(wrap_angle(end.theta - target.theta))
    position_error = math.hypot(end.x - target.x, end.y - target.y)
    line = [(start.x, start.y), (target.x, target.y)]
    return {
        "start": start._asdict(),
        "end": end._asdict(),
        "driven_m": sum(math.hypot(b.x - a.x, b.y - a.y) for a, b in itertools.pairwise(driven)),
        "path_error_max_m": max(distance_to_path((pose.x, pose.y), line) for pose in driven),
        "position_error_m": position_error,
        "heading_error_rad": heading_error,
        "within_tolerance": position_error <= target.position_tolerance
        and (heading_error is None or heading_error <= target.heading_tolerance),
    }


def goal_lines(goals: Sequence[dict[str, Any]], most: int = 10) -> list[str]:
    """The summary's lines of a goal-mode run: how many goals ended how, then the first ``most`` goals."""
    if not goals:
        return []
    counts = Counter(goal["outcome"] or "running at the end" for goal in goals)
    lines = [f"goals: {len(goals)} (" + ", ".join(f"{word} {count}" for word, count in counts.items()) + ")"]
    for goal in goals[:most]:
        pose = goal["pose"]
        where = ""
        if pose is not None:
            heading = "" if pose["theta"] is None else f", {math.degrees(pose['theta']):.1f} deg"
            where = f" to ({pose['x']:.3f}, {pose['y']:.3f}{heading})"
        if goal["outcome"] is None:
            how = "still running when the recording ended"
        else:
            how = f"{goal['outcome']} after {goal['elapsed_s']:.2f} s" + (
                f" ({goal['reason']})" if goal["reason"] else ""
            )
        truth = goal["ground_truth"]
        off = ""
        if truth is not None:
            off = f"; ground truth {truth['position_error_m'] * 100:.1f} cm"
            if truth["heading_error_rad"] is not None:
                off += f", {math.degrees(truth['heading_error_rad']):.1f} deg"
            off += " off"
        lines.append(f"  goal {goal['id']}{where}: {how}{off}")
    if len(goals) > most:
        lines.append(f"  ... and {len(goals) - most} more goals (report.json: goals)")
    return lines
