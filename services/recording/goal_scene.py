"""The drive's goals in Foxglove's 3D scene (docs/protocol.md section 7.3), pure (no zenoh):
:class:`GoalDrawing` takes the goal mode's messages (``drive/goal``: each goal as it starts;
``drive/goal/feedback``: its progress; ``drive/outcome`` with a ``goal_id``: how it ended) and the
ground truth, and gives the entities :class:`services.recording.scene.Scene` puts into every scene
update:

- ``goal``: the running goal (or the last one, once ended) in ``world``: an arrow at its position
  along its heading (a sphere when it has none), its position tolerance as a circle on the ground
  and its heading tolerance as two lines either side of the arrow, and a label: its id and, while
  it runs, its state (``executing``, ``canceling``), the distance remaining, the time elapsed and
  the estimate of the time remaining (the last feedback); once ended, its outcome, the reason and
  how long it ran. Running it is amber; ended it is green (``completed``), grey (``canceled``) or
  red (``aborted``, ``timed_out``);
- ``goal_path``: the path driven to it, the ground truth from the goal's start to its end (the
  newest :data:`~services.recording.scene.TRAIL_POINTS` points, as the trails keep), drawn over
  the run's own trail in the goal's colour;
- ``goals_ended``: the goals before it (the newest :data:`ENDED_GOALS`), each a small marker in
  its outcome's colour with its id and outcome: a preempted goal stays visible, ``canceled``.

A goal without a heading has no heading tolerance to draw. An empty entity is sent while there
is no goal, so a viewer that seeks back before the first goal shows none. What the drive never
publishes (a tolerance or a time limit ≤ 0, an id that is not a goal id) does not decode as a
``GoalTarget``: bad input, refused before it changes anything.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from foxglove.messages import (
    ArrowPrimitive,
    Color,
    LinePrimitive,
    LinePrimitiveLineType,
    SceneEntity,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from schemas.messages import ScenarioOutcome
from schemas.navigation import GoalFeedback, GoalTarget
from services.recording.scene_shapes import foxglove_pose, ground_line, yaw_quaternion

ENDED_GOALS = 8
"""Ended goals drawn besides the running one (the newest)."""
CIRCLE_SEGMENTS = 48
"""Segments of the position tolerance's circle."""
ARROW_LENGTH_M = 0.3
MARKER_DIAMETER_M = 0.06
LABEL_REASON_CHARACTERS = 120
"""The longest reason a label shows (an outcome's reason, cut with an ellipsis)."""
GROUND_Z = 0.012
"""Height of the goal's drawing: above the trails (1 cm), below the robot."""
LABEL_Z = 0.25

RUNNING = Color(r=1.0, g=0.7, b=0.0, a=1.0)
OUTCOME_COLORS = {
    "completed": Color(r=0.1, g=0.8, b=0.3, a=1.0),
    "canceled": Color(r=0.55, g=0.55, b=0.55, a=1.0),
    "aborted": Color(r=0.9, g=0.15, b=0.15, a=1.0),
    "timed_out": Color(r=0.9, g=0.15, b=0.15, a=1.0),
}
_LABEL = Color(r=1.0, g=1.0, b=1.0, a=1.0)


class _Points:
    """A polyline that keeps a point every ``spacing`` m, the newest ``limit``."""

    def __init__(self, spacing: float, limit: int) -> None:
        self.spacing = spacing
        self.points: deque[tuple[float, float]] = deque(maxlen=limit)

    def add(self, x: float, y: float) -> None:
        if not self.points or math.dist(self.points[-1], (x, y)) >= self.spacing:
            self.points.append((x, y))


@dataclass
class Goal:
    """One goal as the scene knows it."""

    target: GoalTarget
    path: _Points
    feedback: GoalFeedback | None = None
    outcome: ScenarioOutcome | None = None

    @property
    def started_ns(self) -> int:
        return self.target.tm.to_nanoseconds()

    def ends_with(self, outcome: ScenarioOutcome) -> bool:
        """Whether ``outcome`` is this goal's: its id, at or after its start, and none before."""
        return (
            self.outcome is None
            and outcome.goal_id == self.target.id
            and outcome.tm.to_nanoseconds() >= self.started_ns
        )


class GoalDrawing:
    """The goals of one robot, drawn; ``ids``: the entity ids (``goal``, ``goal_path``,
    ``goals_ended``, each with the robot's prefix in a fleet); ``spacing`` and ``limit``: the driven
    path's spacing (m) and its most points, as the scene's trails."""

    def __init__(self, ids: dict[str, str], spacing: float, limit: int) -> None:
        self._ids = ids
        self._spacing = spacing
        self._limit = limit
        self.current: Goal | None = None
        self.ended: deque[Goal] = deque(maxlen=ENDED_GOALS)
        self._last_outcome: ScenarioOutcome | None = None
        """The latest goal outcome, for a target that comes after its own outcome (a recorder
        started mid-run gets both latched keys, in no set order)."""

    def start(self, target: GoalTarget) -> None:
        """A goal started (``drive/goal``): the one before it, if it had not ended, waits among the
        ended ones for its outcome (a preempted goal ends ``canceled`` at the tick the new one starts)."""
        if self.current is not None and self.current.target == target:
            return  # the latched key's answer to a recorder's query, after the sample itself
        if self.current is not None:
            self.ended.append(self.current)
        self.current = Goal(target, _Points(self._spacing, self._limit))
        last = self._last_outcome
        if last is not None and self.current.ends_with(last):
            self.current.outcome = last

    def feedback(self, feedback: GoalFeedback) -> None:
        """The running goal's progress; a feedback of another goal (one this scene never saw start,
        or one that ended) is not drawn."""
        goal = self.current
        if goal is not None and goal.outcome is None and feedback.id == goal.target.id:
            goal.feedback = feedback

    def end(self, outcome: ScenarioOutcome) -> bool:
        """A goal's outcome (``drive/outcome`` with a ``goal_id``; a scenario's has none and is not a
        goal's): marks the goal it ends. True when a goal drawn changed."""
        if not outcome.goal_id:
            return False
        self._last_outcome = outcome
        for goal in (self.current, *reversed(self.ended)):
            if goal is not None and goal.ends_with(outcome):
                goal.outcome = outcome
                return True
        return False

    def track(self, stamp_ns: int, x: float, y: float) -> None:
        """The ground truth at ``stamp_ns``: a point of the running goal's path if it is within the goal."""
        goal = self.current
        if goal is None or stamp_ns < goal.started_ns:
            return
        if goal.outcome is not None and stamp_ns > goal.outcome.tm.to_nanoseconds():
            return
        goal.path.add(x, y)

    def entities(self, stamp: Timestamp, frame: str) -> list[SceneEntity]:
        """The three entities of the goals, in ``frame`` (the world's)."""
        goal = self.current
        current, path = _Primitives(), _Primitives()
        if goal is not None:
            current.add_goal(goal, ARROW_LENGTH_M, _label(goal), with_tolerances=True)
            if len(goal.path.points) > 1:
                path.lines.append(ground_line(goal.path.points, _color(goal), 0.03, GROUND_Z))
        ended = _Primitives()
        for old in self.ended:
            ended.add_goal(old, ARROW_LENGTH_M / 2, f"{old.target.id}: {_outcome_word(old)}", with_tolerances=False)
        return [
            current.entity(stamp, frame, self._ids["goal"]),
            path.entity(stamp, frame, self._ids["goal_path"]),
            ended.entity(stamp, frame, self._ids["goals_ended"]),
        ]


def _color(goal: Goal) -> Color:
    return RUNNING if goal.outcome is None else OUTCOME_COLORS[goal.outcome.outcome]


def _outcome_word(goal: Goal) -> str:
    return "ended (outcome not seen)" if goal.outcome is None else goal.outcome.outcome


def _short(text: str) -> str:
    return text if len(text) <= LABEL_REASON_CHARACTERS else text[: LABEL_REASON_CHARACTERS - 1] + "…"


def _label(goal: Goal) -> str:
    """The running goal's label: its id and feedback, or its outcome once ended."""
    target, feedback, outcome = goal.target, goal.feedback, goal.outcome
    if outcome is not None:
        reason = f": {_short(outcome.reason)}" if outcome.reason else ""
        return f"{target.id} {outcome.outcome} after {outcome.elapsed_s:.1f} s{reason}"
    if feedback is None:
        return f"{target.id} started"
    return (
        f"{target.id} {feedback.state}: {feedback.distance_remaining:.2f} m to go, "
        f"{feedback.elapsed_s:.1f} s elapsed, about {feedback.estimated_remaining_s:.1f} s left"
    )


@dataclass
class _Primitives:
    """What one entity draws."""

    arrows: list[ArrowPrimitive] = field(default_factory=list)
    spheres: list[SpherePrimitive] = field(default_factory=list)
    lines: list[LinePrimitive] = field(default_factory=list)
    texts: list[TextPrimitive] = field(default_factory=list)

    def add_goal(self, goal: Goal, length: float, text: str, *, with_tolerances: bool) -> None:
        """An arrow ``length`` long along the goal's heading (a sphere without one), its label
        ``text`` and, ``with_tolerances``, the position tolerance's circle and the heading
        tolerance's two lines."""
        target, color = goal.target, _color(goal)
        if target.theta is None:
            diameter = Vector3(x=MARKER_DIAMETER_M, y=MARKER_DIAMETER_M, z=MARKER_DIAMETER_M)
            self.spheres.append(
                SpherePrimitive(pose=foxglove_pose(target.x, target.y, GROUND_Z), size=diameter, color=color)
            )
        else:
            self.arrows.append(
                ArrowPrimitive(
                    pose=foxglove_pose(target.x, target.y, GROUND_Z, yaw_quaternion(target.theta)),
                    shaft_length=0.7 * length,
                    shaft_diameter=0.08 * length,
                    head_length=0.3 * length,
                    head_diameter=0.2 * length,
                    color=color,
                )
            )
        if with_tolerances:
            radius = target.position_tolerance
            circle = [
                (target.x + radius * math.cos(angle), target.y + radius * math.sin(angle))
                for angle in (2.0 * math.pi * i / CIRCLE_SEGMENTS for i in range(CIRCLE_SEGMENTS))
            ]
            self.lines.append(ground_line(circle, color, 0.01, GROUND_Z, LinePrimitiveLineType.LineLoop))
            if target.theta is not None:
                wedge: list[tuple[float, float]] = []
                for side in (-1.0, 1.0):
                    heading = target.theta + side * target.heading_tolerance
                    end = (target.x + length * math.cos(heading), target.y + length * math.sin(heading))
                    wedge += [(target.x, target.y), end]
                self.lines.append(ground_line(wedge, color, 0.005, GROUND_Z, LinePrimitiveLineType.LineList))
        self.texts.append(
            TextPrimitive(
                pose=foxglove_pose(target.x, target.y, LABEL_Z),
                billboard=True,
                font_size=14.0,
                scale_invariant=True,
                color=_LABEL,
                text=text,
            )
        )

    def entity(self, stamp: Timestamp, frame: str, entity_id: str) -> SceneEntity:
        return SceneEntity(
            timestamp=stamp,
            frame_id=frame,
            id=entity_id,
            arrows=self.arrows,
            spheres=self.spheres,
            lines=self.lines,
            texts=self.texts,
        )
