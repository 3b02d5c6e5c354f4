"""The NavigateToPose action server's pure core (no zenoh): what a ROS goal becomes for the drive,
and what the drive's feedback and the goals' states (services/ros2/goal_book.py) become for ROS
(services/ros2/action_server.py is the shell; docs/ros2.md "Navigate" the walkthrough).

- A goal's id is its ROS UUID, 16 bytes, written as 32 lowercase hex digits for the drive
  (``GoalRequest.id``), so the drive's feedback and outcome name it.
- A goal's pose (a ``geometry_msgs/PoseStamped``) may be in any frame of the bridge's TF tree
  (services/ros2/tf_tree.py: ``map``, the bridge's ``odom`` (prefixed on a shared ``/tf``),
  ``base_link`` for a goal relative to the robot, ...): it is turned into ``ros2.map_frame``, the
  drive's ``map``, with the tree's newest transforms, and sent in ``map``. A frame the tree cannot
  transform is a :class:`~services.ros2.tf_tree.TransformError` (the shell accepts the goal and
  aborts it, as Nav2's navigator does); a number not finite, or an orientation that is no
  rotation, is refused.
- A pose estimate on ``initialpose`` (RViz's "2D Pose Estimate", ``geometry_msgs/PoseWithCovarianceStamped``)
  becomes the localization's ``localization/initial_pose`` in ``map`` from ``map`` or the bridge's
  ``odom``, with its covariance's x, y and yaw entries (:func:`initial_pose_request`); the
  bridge's service thread sends it (services/ros2/service.py).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.navigation import GoalFeedback, GoalRequest, InitialPose
from services.planar import Pose
from services.ros2 import core, interfaces
from services.ros2.goal_book import CancelCode, Goal, GoalStatus
from services.ros2.tf_tree import Rigid, TfTree, unit_quaternion


@dataclass(frozen=True)
class GoalFrames:
    """The frame ids a goal may be given in: the map's, and the bridge's odom (prefixed on a shared ``/tf``)."""

    map: str
    odom: str


def unit_orientation(orientation: Any) -> np.ndarray:
    """A peer's ``geometry_msgs/Quaternion`` (any length) normalised before any use
    (:func:`~services.ros2.tf_tree.unit_quaternion`); BadInput for one not finite or zero, which is no rotation."""
    try:
        return unit_quaternion((orientation.x, orientation.y, orientation.z, orientation.w))
    except ValueError as error:
        raise BadInput(str(error)) from None


def yaw_of(orientation: Any) -> float:
    """The heading of a quaternion of any length (:func:`unit_orientation`: BadInput for no rotation)."""
    x, y, z, w = unit_orientation(orientation)
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def goal_request(pose_stamped: Any, tree: TfTree, map_frame: str, goal_id: str, max_coordinate: float) -> GoalRequest:
    """The drive's goal for a ROS goal pose (``geometry_msgs/PoseStamped``), in ``map`` (``map_frame``
    in the tree). BadInput (naming why) for a position or orientation not finite or beyond
    ``max_coordinate`` (in its frame or in ``map``); TransformError for a frame the tree cannot
    turn into ``map_frame``."""
    position = pose_stamped.pose.position
    x, y, z = float(position.x), float(position.y), float(position.z)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise BadInput(f"goal position ({x}, {y}, {z}) is not finite")
    if max(abs(x), abs(y), abs(z)) > max_coordinate:
        raise BadInput(f"goal position ({x}, {y}) is beyond input.max_coordinate {max_coordinate:g} m")
    in_frame = Rigid(np.array([x, y, z]), unit_orientation(pose_stamped.pose.orientation))
    in_map = tree.lookup(map_frame, pose_stamped.header.frame_id).compose(in_frame)
    map_x, map_y = (float(value) for value in in_map.translation[:2])
    if max(abs(map_x), abs(map_y)) > max_coordinate:
        raise BadInput(
            f"goal ({map_x:g}, {map_y:g}) in {map_frame!r} is beyond input.max_coordinate {max_coordinate:g} m"
        )
    return GoalRequest(x=map_x, y=map_y, theta=in_map.yaw, frame="map", id=goal_id)


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
    qx, qy, _, _ = unit_orientation(orientation)
    if math.hypot(qx, qy) > MAX_TILT:
        raise BadInput(
            f"orientation ({orientation.x}, {orientation.y}, {orientation.z}, {orientation.w}) is not a turn about z"
        )
    theta = yaw_of(orientation)
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


MAX_DURATION_S = 2**31 - 1
"""A ``builtin_interfaces/Duration``'s most whole seconds (its ``sec`` is an int32)."""


def duration(seconds: float) -> Any:
    """builtin_interfaces/Duration of ``seconds`` (negative or not finite: 0; beyond
    :data:`MAX_DURATION_S`, as a peer's feedback may say: that, not an overflow)."""
    within = min(seconds, MAX_DURATION_S)
    total_ns = round(within * NANOSECONDS_PER_SECOND) if math.isfinite(seconds) and seconds > 0 else 0
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


def status_array(goals: list[Goal], shown: Mapping[bytes, GoalStatus] | None = None) -> Any:
    """``action_msgs/GoalStatusArray`` of ``goals``, each with its status or the one ``shown`` for it
    (a state it passes through: goal_book.transitions)."""
    status = interfaces.message_class(interfaces.GOAL_STATUS)
    override = shown or {}
    return interfaces.message_class(interfaces.GOAL_STATUS_ARRAY)(
        status_list=[
            status(goal_info=goal_info(goal.uuid, goal.stamp_ns or 0), status=int(override.get(goal.uuid, goal.status)))
            for goal in goals
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
    frame_errors: int = 0
    """Goals accepted and aborted at once: their frame not in the bridge's TF tree (Nav2's TF_ERROR)."""
    results_refused: int = 0
    """``get_result`` calls answered with an error: more than the held results' bounds."""
    expired: int = 0
    """Ended goals forgotten: ``ros2.result_timeout`` after they ended, or beyond the count kept."""

    def ended(self, status: GoalStatus) -> None:
        if status is GoalStatus.SUCCEEDED:
            self.succeeded += 1
        elif status is GoalStatus.CANCELED:
            self.canceled += 1
        else:
            self.aborted += 1
