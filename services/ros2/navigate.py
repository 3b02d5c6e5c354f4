"""The NavigateToPose action server's pure core (no zenoh): what a ROS goal becomes for the drive,
what the drive's feedback and outcomes become for ROS, and the goals' states as rcl_action keeps
them (services/ros2/action_server.py is the shell; docs/ros2.md "Navigate" the walkthrough).

- A goal's id is its ROS UUID, 16 bytes, written as 32 lowercase hex digits for the drive
  (``GoalRequest.id``), so the drive's feedback and outcome name it.
- A goal's pose (a ``geometry_msgs/PoseStamped``) is in ``ros2.map_frame``, which is the drive's
  ``map``, or in ``ros2.odom_frame`` (prefixed on a shared ``/tf``), which is the bridge's own
  ``odom`` (docs/ros2.md "Frames": where the bridge started integrating, not the drive's): it is
  turned into ``map`` with the bridge's current ``map -> odom`` and sent in ``map``. Any other frame,
  a number not finite, or an orientation that is no rotation is refused.
- A pose estimate on ``initialpose`` (RViz's "2D Pose Estimate", ``geometry_msgs/PoseWithCovarianceStamped``)
  becomes the localization's ``localization/initial_pose`` the same way, in ``map``, with its
  covariance's x, y and yaw entries (:func:`initial_pose_request`); the bridge's service thread
  sends it (services/ros2/service.py).
- Status codes, cancel policy and return codes are rcl_action's (``action_msgs/msg/GoalStatus``,
  ``action_msgs/srv/CancelGoal``; ``rcl_action_process_cancel_request``).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, GoalFeedback, GoalRequest, InitialPose, ScenarioOutcome
from services.planar import Pose
from services.ros2 import core, interfaces

UUID_BYTES = 16
ZERO_UUID = bytes(UUID_BYTES)
MAX_GOALS = 64
"""Goals the server keeps at most (running, and ended ones for their status and result)."""
MAX_ENDED_GOALS = 16
"""Ended goals kept for ``_action/status`` and ``get_result`` (the oldest is forgotten first):
rcl_action keeps them for ``result_timeout`` (15 min by default); a fixed number bounds the memory."""


class GoalStatus(IntEnum):
    """``action_msgs/msg/GoalStatus``'s status codes."""

    UNKNOWN = 0
    ACCEPTED = 1
    EXECUTING = 2
    CANCELING = 3
    SUCCEEDED = 4
    CANCELED = 5
    ABORTED = 6

    @property
    def terminal(self) -> bool:
        return self in (GoalStatus.SUCCEEDED, GoalStatus.CANCELED, GoalStatus.ABORTED)

    @property
    def cancelable(self) -> bool:
        """rcl_action's goal state machine takes a cancel only from accepted and executing."""
        return self in (GoalStatus.ACCEPTED, GoalStatus.EXECUTING)


class CancelCode(IntEnum):
    """``action_msgs/srv/CancelGoal``'s return codes."""

    NONE = 0
    REJECTED = 1
    UNKNOWN_GOAL_ID = 2
    GOAL_TERMINATED = 3


class ErrorCode(IntEnum):
    """``NavigateToPose_Result.error_code``. Jazzy's ``.action`` defines only ``NONE``; the others
    are the codes Nav2's navigator uses from Kilted on (its ``.action`` adds them as constants,
    which do not change the type or its hash: the field is the same ``uint16``)."""

    NONE = 0
    UNKNOWN = 9000
    TIMEOUT = 9003


OUTCOMES: dict[str, tuple[GoalStatus, ErrorCode]] = {
    "completed": (GoalStatus.SUCCEEDED, ErrorCode.NONE),
    "canceled": (GoalStatus.CANCELED, ErrorCode.NONE),
    "aborted": (GoalStatus.ABORTED, ErrorCode.UNKNOWN),
    "timed_out": (GoalStatus.ABORTED, ErrorCode.TIMEOUT),
}
"""The drive's outcome of a goal -> its final status and result's error code."""


def goal_id_of(uuid: bytes) -> str:
    """A ROS goal's UUID as the drive's goal id: 32 lowercase hex digits."""
    if len(uuid) != UUID_BYTES:
        raise BadInput(f"a goal UUID of {len(uuid)} bytes, not {UUID_BYTES}")
    return uuid.hex()


def uuid_of(goal_id: str) -> bytes | None:
    """The UUID a drive goal id stands for; None for one that is not a ROS goal's (``g3``)."""
    if len(goal_id) != 2 * UUID_BYTES:
        return None
    try:
        return bytes.fromhex(goal_id)
    except ValueError:
        return None


@dataclass(frozen=True)
class GoalFrames:
    """The frame ids a goal may be given in: the map's, and the bridge's odom (prefixed on a shared ``/tf``)."""

    map: str
    odom: str


def yaw_of(orientation: Any) -> float:
    """The heading of a quaternion (any length: it is normalised); BadInput for one that is not
    finite or is (nearly) zero, which is no rotation."""
    x, y, z, w = (float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w))
    if not all(math.isfinite(value) for value in (x, y, z, w)):
        raise BadInput(f"orientation ({x}, {y}, {z}, {w}) is not finite")
    if x * x + y * y + z * z + w * w < 1e-12:
        raise BadInput("orientation (0, 0, 0, 0) is no rotation")
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def goal_request(
    pose_stamped: Any, frames: GoalFrames, map_to_odom: Pose | None, goal_id: str, max_coordinate: float
) -> GoalRequest:
    """The drive's goal for a ROS goal pose (``geometry_msgs/PoseStamped``), in ``map``; BadInput
    (naming why) for a frame neither ``frames.map`` nor ``frames.odom``, an odom goal before the
    bridge has a ``map -> odom``, or a position or orientation not finite or beyond ``max_coordinate``."""
    position = pose_stamped.pose.position
    x, y = float(position.x), float(position.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise BadInput(f"goal position ({x}, {y}) is not finite")
    if max(abs(x), abs(y)) > max_coordinate:
        raise BadInput(f"goal position ({x}, {y}) is beyond input.max_coordinate {max_coordinate:g} m")
    theta = yaw_of(pose_stamped.pose.orientation)
    pose = _in_map(Pose(x, y, theta), pose_stamped.header.frame_id, frames, map_to_odom, "a goal")
    return GoalRequest(x=pose.x, y=pose.y, theta=pose.theta, frame="map", id=goal_id)


def _in_map(pose: Pose, frame: str, frames: GoalFrames, map_to_odom: Pose | None, what: str) -> Pose:
    """``pose``, given in ``frame``, in ``map``; BadInput for a frame neither ``frames.map`` nor
    ``frames.odom``, or ``odom`` before the bridge has a ``map -> odom``."""
    if frame == frames.map:
        return pose
    if frame == frames.odom:
        if map_to_odom is None:
            raise BadInput(f"{what} in {frame!r} before the bridge has map -> odom (no localized pose yet)")
        return core.compose(map_to_odom, pose)
    raise BadInput(f"frame {frame!r} is neither {frames.map!r} nor {frames.odom!r}")


MAX_TILT = 1e-3
"""The most a pose estimate's orientation may lean off a turn about z: ``sqrt(x² + y²)`` of the
normalised quaternion (a tilt of about 0.11°)."""


def initial_pose_request(
    message: Any, frames: GoalFrames, map_to_odom: Pose | None, max_coordinate: float
) -> InitialPose:
    """The localization's ``localization/initial_pose`` payload for a ROS pose estimate
    (``geometry_msgs/PoseWithCovarianceStamped``: RViz's "2D Pose Estimate" on ``initialpose``), in
    ``map``: its position, its heading, and its covariance's x, y and yaw entries (turned with the
    pose when it is given in ``odom``; none when they are all zero: the localization's own initial
    spread). BadInput (naming why) for a frame neither ``frames.map`` nor ``frames.odom``, an odom pose
    before the bridge has a ``map -> odom``, a number not finite, a position beyond
    ``max_coordinate`` (in either frame), an orientation that is no turn about z (more than
    :data:`MAX_TILT`), or a negative variance."""
    position = message.pose.pose.position
    x, y = float(position.x), float(position.y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise BadInput(f"initial pose position ({x}, {y}) is not finite")
    if max(abs(x), abs(y)) > max_coordinate:
        raise BadInput(f"initial pose position ({x}, {y}) is beyond input.max_coordinate {max_coordinate:g} m")
    orientation = message.pose.pose.orientation
    theta = yaw_of(orientation)
    qx, qy, qz, qw = (float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w))
    tilt = math.hypot(qx, qy) / math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if tilt > MAX_TILT:
        raise BadInput(f"orientation ({qx}, {qy}, {qz}, {qw}) is not a turn about z")
    covariance = core.planar_covariance(message.pose.covariance)
    if np.any(np.diag(covariance) < 0.0):
        raise BadInput(f"the covariance's variances {np.diag(covariance).tolist()} are not all non-negative")
    frame = message.header.frame_id
    pose = _in_map(Pose(x, y, theta), frame, frames, map_to_odom, "an initial pose")
    if frame != frames.map and map_to_odom is not None:
        cos, sin = math.cos(map_to_odom.theta), math.sin(map_to_odom.theta)
        turn = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
        covariance = turn @ covariance @ turn.T
        if max(abs(pose.x), abs(pose.y)) > max_coordinate:
            raise BadInput(
                f"initial pose ({pose.x:g}, {pose.y:g}) in {frames.map!r} is beyond input.max_coordinate {max_coordinate:g} m"
            )
    values = core.upper_triangle(covariance) if np.any(covariance != 0.0) else []
    return InitialPose(x=pose.x, y=pose.y, theta=pose.theta, covariance=values)


def duration(seconds: float) -> Any:
    """builtin_interfaces/Duration of ``seconds`` (negative or not finite: 0)."""
    total_ns = round(seconds * NANOSECONDS_PER_SECOND) if math.isfinite(seconds) and seconds > 0 else 0
    sec, nanosec = divmod(total_ns, NANOSECONDS_PER_SECOND)
    return interfaces.message_class("builtin_interfaces/msg/Duration")(sec=sec, nanosec=nanosec)


def uuid_message(uuid: bytes) -> Any:
    """``unique_identifier_msgs/UUID`` of 16 bytes."""
    return interfaces.message_class(interfaces.UUID)(uuid=np.frombuffer(uuid, dtype=np.uint8).copy())


def uuid_bytes(message: Any) -> bytes:
    """The 16 bytes of a ``unique_identifier_msgs/UUID``."""
    return bytes(bytearray(message.uuid))


def feedback_message(uuid: bytes, feedback: GoalFeedback, map_frame: str) -> Any:
    """``NavigateToPose_FeedbackMessage`` of the drive's feedback: the robot's pose in the map
    frame, the time it has driven and the estimate of the rest, the recoveries its navigation has tried
    (int16: capped at 32767), the distance left."""
    stamp_ns = feedback.tm.to_nanoseconds()
    pose = core.planar_pose(feedback.x, feedback.y, feedback.theta)
    return interfaces.message_class(interfaces.NAVIGATE_TO_POSE_FEEDBACK_MESSAGE)(
        goal_id=uuid_message(uuid),
        feedback=interfaces.message_class(interfaces.NAVIGATE_TO_POSE_FEEDBACK)(
            current_pose=interfaces.message_class(interfaces.POSE_STAMPED)(
                header=core.header(stamp_ns, map_frame), pose=pose
            ),
            navigation_time=duration(feedback.elapsed_s),
            estimated_time_remaining=duration(feedback.estimated_remaining_s),
            number_of_recoveries=min(feedback.recoveries, 32767),
            distance_remaining=float(feedback.distance_remaining),
        ),
    )


def goal_info(uuid: bytes, stamp_ns: int) -> Any:
    return interfaces.message_class(interfaces.GOAL_INFO)(goal_id=uuid_message(uuid), stamp=core.ros_time(stamp_ns))


@dataclass
class Goal:
    """One goal the server knows: sent (awaiting the drive's reply), accepted, running, or ended."""

    uuid: bytes
    stamp_ns: int | None = None
    """When the drive accepted it (simulation time); None while its send waits for the drive."""
    status: GoalStatus = GoalStatus.UNKNOWN
    error_code: ErrorCode = ErrorCode.NONE
    error_msg: str = ""

    @property
    def id(self) -> str:
        return goal_id_of(self.uuid)


class GoalBook:
    """The goals of one action server, in the order they were sent, and their states as rcl_action
    moves them: accepted, executing, canceling, then succeeded, canceled or aborted. Events may
    come in any order from the drive's keys (its outcome before the reply to the send): a later
    state is never undone by an earlier one. At most :data:`MAX_ENDED_GOALS` ended goals are kept."""

    def __init__(self, max_goals: int = MAX_GOALS, max_ended: int = MAX_ENDED_GOALS) -> None:
        self._goals: OrderedDict[bytes, Goal] = OrderedDict()
        self._max_goals = max_goals
        self._max_ended = max_ended

    def __contains__(self, uuid: bytes) -> bool:
        return uuid in self._goals

    def get(self, uuid: bytes) -> Goal | None:
        return self._goals.get(uuid)

    def by_id(self, goal_id: str) -> Goal | None:
        """The goal a drive goal id names, if it is one of these."""
        uuid = uuid_of(goal_id)
        return None if uuid is None else self._goals.get(uuid)

    def send(self, uuid: bytes) -> Goal:
        """A goal about to be sent to the drive; BadInput for a UUID already known (rcl_action
        refuses a goal id that exists) or when the book is full of goals still running."""
        if uuid in self._goals:
            raise BadInput(f"goal {goal_id_of(uuid)} exists already")
        if len(self._goals) >= self._max_goals and not self._forget_ended(keep=len(self._goals) - self._max_goals + 1):
            raise BadInput(f"{self._max_goals} goals are running or waiting for the drive")
        goal = self._goals[uuid] = Goal(uuid)
        return goal

    def rejected(self, uuid: bytes) -> None:
        """The drive refused it (or never answered): forgotten, as if never sent."""
        goal = self._goals.get(uuid)
        if goal is not None and goal.stamp_ns is None:
            del self._goals[uuid]

    def accepted(self, uuid: bytes, stamp_ns: int) -> bool:
        """The drive accepted it at ``stamp_ns``: ``accepted`` (unless already further); True if
        the status list changed."""
        goal = self._goals.get(uuid)
        if goal is None or goal.stamp_ns is not None:
            return False
        goal.stamp_ns = stamp_ns
        if goal.status is GoalStatus.UNKNOWN:
            goal.status = GoalStatus.ACCEPTED
        return True

    def executing(self, goal_id: str) -> bool:
        """The drive started it (``drive/goal``) or reports it executing; True if it changed."""
        return self._advance(goal_id, GoalStatus.EXECUTING)

    def canceling(self, goal_id: str) -> bool:
        return self._advance(goal_id, GoalStatus.CANCELING)

    def _advance(self, goal_id: str, status: GoalStatus) -> bool:
        goal = self.by_id(goal_id)
        if goal is None or goal.status.terminal or goal.status >= status:
            return False
        goal.status = status
        return goal.stamp_ns is not None

    def ended(self, outcome: ScenarioOutcome) -> Goal | None:
        """The drive's outcome of a goal: its final status and result; the goal, if it is one of
        these and had not ended yet."""
        goal = self.by_id(outcome.goal_id)
        if goal is None or goal.status.terminal:
            return None
        goal.status, goal.error_code = OUTCOMES[outcome.outcome]
        goal.error_msg = outcome.reason
        self._forget_ended()
        return goal

    def _forget_ended(self, keep: int = 0) -> bool:
        """Forget the oldest ended goals beyond :attr:`_max_ended`, and ``keep`` more; True if
        at least ``keep`` were forgotten."""
        ended = [uuid for uuid, goal in self._goals.items() if goal.status.terminal]
        excess = max(len(ended) - self._max_ended, keep)
        for uuid in ended[:excess]:
            del self._goals[uuid]
        return len(ended) >= keep

    def cancel(self, uuid: bytes, stamp_ns: int) -> tuple[CancelCode, list[Goal]]:
        """rcl_action's cancel policy: a zero UUID and zero stamp cancel every goal; a zero UUID and
        a stamp, every goal accepted at or before it; a UUID and zero stamp, that goal (unknown: 2,
        no longer cancelable: 3); a UUID and a stamp, that goal and those before. The goals that
        move to ``canceling`` (marked so here), with return code 0 (even when none does, but for a
        single goal)."""
        if uuid != ZERO_UUID and stamp_ns == 0:
            goal = self._goals.get(uuid)
            if goal is None or goal.stamp_ns is None:
                return CancelCode.UNKNOWN_GOAL_ID, []
            if not goal.status.cancelable:
                return CancelCode.GOAL_TERMINATED, []
            goal.status = GoalStatus.CANCELING
            return CancelCode.NONE, [goal]
        before_ns = stamp_ns if stamp_ns != 0 or uuid != ZERO_UUID else None
        canceling = [
            goal
            for goal in self._goals.values()
            if goal.stamp_ns is not None
            and goal.status.cancelable
            and (before_ns is None or goal.stamp_ns <= before_ns or goal.uuid == uuid)
        ]
        for goal in canceling:
            goal.status = GoalStatus.CANCELING
        return CancelCode.NONE, canceling

    def status_list(self) -> list[Goal]:
        """The goals ``_action/status`` lists: every accepted one, ended ones kept, in order."""
        return [goal for goal in self._goals.values() if goal.stamp_ns is not None]

    def running(self) -> list[Goal]:
        return [goal for goal in self.status_list() if not goal.status.terminal]


def status_array(goals: list[Goal]) -> Any:
    """``action_msgs/GoalStatusArray`` of ``goals``."""
    status = interfaces.message_class(interfaces.GOAL_STATUS)
    return interfaces.message_class(interfaces.GOAL_STATUS_ARRAY)(
        status_list=[
            status(goal_info=goal_info(goal.uuid, goal.stamp_ns or 0), status=int(goal.status)) for goal in goals
        ]
    )


def result_response(goal: Goal | None) -> Any:
    """``NavigateToPose_GetResult_Response`` of an ended goal (or of one unknown: status 0)."""
    result = interfaces.message_class(interfaces.NAVIGATE_TO_POSE_RESULT)(
        error_code=int(goal.error_code) if goal is not None else 0, error_msg=goal.error_msg if goal is not None else ""
    )
    return interfaces.message_class(f"{interfaces.NAVIGATE_TO_POSE_GET_RESULT}_Response")(
        status=int(goal.status) if goal is not None else int(GoalStatus.UNKNOWN), result=result
    )


def send_goal_response(accepted: bool, stamp_ns: int) -> Any:
    return interfaces.message_class(f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Response")(
        accepted=accepted, stamp=core.ros_time(stamp_ns)
    )


def cancel_response(code: CancelCode, goals: list[Goal]) -> Any:
    return interfaces.message_class(interfaces.CANCEL_GOAL_RESPONSE)(
        return_code=int(code), goals_canceling=[goal_info(goal.uuid, goal.stamp_ns or 0) for goal in goals]
    )


@dataclass
class Counters:
    """The action server's counts, for its status."""

    sent: int = 0
    accepted: int = 0
    rejected: int = 0
    succeeded: int = 0
    canceled: int = 0
    aborted: int = 0
    cancel_requests: int = 0
    result_requests: int = 0
    last_rejection: str = ""
    """Why the last goal was refused (SendGoal's response cannot say)."""

    def ended(self, status: GoalStatus) -> None:
        if status is GoalStatus.SUCCEEDED:
            self.succeeded += 1
        elif status is GoalStatus.CANCELED:
            self.canceled += 1
        else:
            self.aborted += 1
