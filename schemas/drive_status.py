"""The drive's and the ROS 2 bridge's status replies (docs/drive.md, docs/ros2.md), as
:mod:`schemas.status` types the others'. A field a mode has not is absent from the reply (unset)."""

from __future__ import annotations

import msgspec
from msgspec import UNSET, UnsetType

from schemas.status import PlanarPose, ServiceStatus, UserLockstep, Velocity


class NavigatorStatus(msgspec.Struct):
    """The running goal's navigator: its phase, recoveries, replans, plan and what is left of it."""

    phase: str
    recovery: str | None
    recoveries: int
    replans: int
    plan_length: float | None
    remaining: float | None
    failure: str


class RunningGoalStatus(msgspec.Struct):
    id: str
    phase: str
    x: float
    y: float
    theta: float | None
    attempt: int
    time_limit_s: float | None
    navigation: NavigatorStatus | None


class EndedGoal(msgspec.Struct):
    id: str
    outcome: str
    reason: str
    elapsed_s: float


class GoalsStatus(msgspec.Struct, kw_only=True):
    """``drive/status``'s ``goals`` in goal mode: the goal running, the one pending, the last ended,
    the counts of each outcome, and what was published and sent from a goal file."""

    running: RunningGoalStatus | None
    pending: str | None
    last: EndedGoal | None
    accepted: int
    rejected: int
    completed: int
    canceled: int
    aborted: int
    timed_out: int
    cancel_rejected: int
    feedback_published: int
    file_entries_sent: int | None
    file_entries: int | None


class DriveNavigationStatus(msgspec.Struct, kw_only=True):
    """``drive/status``'s ``navigation`` (docs/navigation.md): the map, the scans taken into the costmap."""

    map: str | None
    scans: int
    scans_dropped: int
    scans_late: int
    scans_without_pose: int
    costmap: dict[str, int]
    mapping: dict[str, int] | None


class DriveOutcome(msgspec.Struct):
    outcome: str
    reason: str


class DriveStatus(ServiceStatus, kw_only=True):
    """``drive/status``: the built-in drive's, in a scenario's mode or goal mode, or a user service
    that drives in its place (``mode`` ``user_service``, with the runtime's fields)."""

    state: str
    mode: str
    rate_hz: float
    commands_published: int
    command: Velocity
    lockstep_participant: bool
    time_base_restarts: int
    sim_alive: bool
    motor_stopped_since_s: float | None
    motor_held_since_s: float | None
    motor_held_by: str | None
    outcome: DriveOutcome | None
    # the built-in drive's
    odometry_alive: bool | UnsetType = UNSET
    pose_wait_timeouts: int | UnsetType = UNSET
    time_limit_s: float | None | UnsetType = UNSET
    pose: PlanarPose | None | UnsetType = UNSET
    pose_age_s: float | None | UnsetType = UNSET
    # a scenario's
    scenario: str | UnsetType = UNSET
    loop: bool | UnsetType = UNSET
    iteration: int | UnsetType = UNSET
    segment_index: int | UnsetType = UNSET
    segments: int | UnsetType = UNSET
    elapsed_s: float | UnsetType = UNSET
    waypoint_index: int | None | UnsetType = UNSET
    follower_phase: str | None | UnsetType = UNSET
    done: bool | UnsetType = UNSET
    # goal mode's
    goals: GoalsStatus | UnsetType = UNSET
    navigation: DriveNavigationStatus | None | UnsetType = UNSET
    # a user service's that drives
    driven_by: str | UnsetType = UNSET
    motor_state: str | None | UnsetType = UNSET
    sim_time_s: float | None | UnsetType = UNSET
    lockstep: UserLockstep | None | UnsetType = UNSET
    outputs: dict[str, int] | UnsetType = UNSET
    calls: dict[str, int] | UnsetType = UNSET


class NavigateWaiting(msgspec.Struct):
    """The action's calls held: goals sent to the drive not yet answered, results not yet ended."""

    sends: int
    results: int


class NavigateStatus(msgspec.Struct, kw_only=True):
    """The NavigateToPose action server's (services/ros2/action_server.py, its counts: ``navigate.Counters``)."""

    action: str
    drive_serves_goals: bool
    sent: int
    accepted: int
    rejected: int
    succeeded: int
    canceled: int
    aborted: int
    cancel_requests: int
    result_requests: int
    last_rejection: str
    frame_errors: int
    results_refused: int
    expired: int
    waiting: NavigateWaiting
    goals: dict[str, str]
    """Each goal kept, by id, and its status (lower case, as ``GoalStatus``)."""


class InitialPoseStatus(msgspec.Struct, kw_only=True):
    """``/initialpose``'s: the poses received and what the localization answered."""

    received: int
    accepted: int
    refused: int
    unanswered: int
    waiting: int
    last_refusal: str


class Ros2Status(ServiceStatus, kw_only=True):
    """``ros2/status`` (docs/ros2.md): the node, what it published, forwarded and answered."""

    state: str
    domain: int
    namespace: str
    node: str
    zid: str
    sim_alive: bool
    sim_time_s: float | None
    time_base_restarts: int
    published: dict[str, int]
    cmd_vel: dict[str, int]
    service_calls: dict[str, int]
    odometry_services: dict[str, int]
    navigate: NavigateStatus | UnsetType = UNSET
    """When it serves the action."""
    initial_pose: InitialPoseStatus | UnsetType = UNSET
    """When a localization takes it."""
    odom: PlanarPose
