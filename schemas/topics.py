"""What each key of docs/protocol.md section 2 carries: the data keys (:class:`Topic`) with their
message types, the latched ones and the vector layouts; the queryables' methods (the Motor
interface's, the drive's goals', the localization's, the odometry's) with their payloads and
replies. The keys themselves are built by :class:`schemas.keys.Keys`.
"""

from __future__ import annotations

from enum import StrEnum

import msgspec

from schemas.messages import (
    BumpEvent,
    ImuSample,
    LaserScan,
    MotorStateReport,
    NoArguments,
    PDGains,
    PlannedPath,
    RunSummary,
    ScenarioOutcome,
    SetOdometry,
    SetOdometryReply,
    SimWorld,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.navigation import (
    CancelReply,
    CancelRequest,
    GoalFeedback,
    GoalPlan,
    GoalReply,
    GoalRequest,
    GoalTarget,
    InitialPose,
    LocalizationReply,
    OccupancyGrid,
    ParticleCloud,
)


class Topic(StrEnum):
    """Data keys, relative to ``invent/<robot>/``."""

    SIM_WHEEL_ANGLES = "sim/wheel_angles"
    SIM_CLOCK = "sim/clock"
    SIM_BODY_POSE = "sim/body_pose"
    SIM_BUMP = "sim/bump"
    SIM_SCAN = "sim/scan"
    SIM_IMU = "sim/imu"
    MOTOR_TORQUE = "motor/torque"
    MOTOR_WHEEL_VELOCITY = "motor/wheel_velocity"
    MOTOR_WHEEL_ANGLES = "motor/wheel_angles"
    MOTOR_SIM_POSE_GUI = "motor/sim_pose/gui"
    MOTOR_SIM_POSE_LOCALIZATION = "motor/sim_pose/localization"
    DRIVE_TARGET_VELOCITY = "drive/target_velocity"
    ODOMETRY_POSE = "odometry/pose"
    LOCALIZATION_POSE = "localization/pose"
    LOCALIZATION_PARTICLES = "localization/particles"
    SIM_WORLD = "sim/world"
    DRIVE_PATH = "drive/path"
    MOTOR_STATE = "motor/state"
    DRIVE_OUTCOME = "drive/outcome"
    DRIVE_GOAL = "drive/goal"
    DRIVE_GOAL_FEEDBACK = "drive/goal/feedback"
    DRIVE_MAP = "drive/map"
    DRIVE_COSTMAP = "drive/costmap"
    DRIVE_PLAN = "drive/plan"
    RUN_SUMMARY = "up/run"


TopicMessage = (
    TimedDoubleSeq
    | TimedVelocity
    | TimedPosition
    | BumpEvent
    | LaserScan
    | ImuSample
    | SimWorld
    | PlannedPath
    | MotorStateReport
    | ScenarioOutcome
    | GoalTarget
    | GoalFeedback
    | OccupancyGrid
    | GoalPlan
    | RunSummary
    | ParticleCloud
)
"""What a data key carries: every one has its ``tm`` stamp."""

TOPIC_TYPES: dict[Topic, type[TopicMessage]] = {
    Topic.SIM_WHEEL_ANGLES: TimedDoubleSeq,
    Topic.SIM_CLOCK: TimedDoubleSeq,
    Topic.SIM_BODY_POSE: TimedDoubleSeq,
    Topic.SIM_BUMP: BumpEvent,
    Topic.SIM_SCAN: LaserScan,
    Topic.SIM_IMU: ImuSample,
    Topic.MOTOR_TORQUE: TimedDoubleSeq,
    Topic.MOTOR_WHEEL_VELOCITY: TimedDoubleSeq,
    Topic.MOTOR_WHEEL_ANGLES: TimedDoubleSeq,
    Topic.MOTOR_SIM_POSE_GUI: TimedDoubleSeq,
    Topic.MOTOR_SIM_POSE_LOCALIZATION: TimedDoubleSeq,
    Topic.DRIVE_TARGET_VELOCITY: TimedVelocity,
    Topic.ODOMETRY_POSE: TimedPosition,
    Topic.LOCALIZATION_POSE: TimedPosition,
    Topic.LOCALIZATION_PARTICLES: ParticleCloud,
    Topic.SIM_WORLD: SimWorld,
    Topic.DRIVE_PATH: PlannedPath,
    Topic.MOTOR_STATE: MotorStateReport,
    Topic.DRIVE_OUTCOME: ScenarioOutcome,
    Topic.DRIVE_GOAL: GoalTarget,
    Topic.DRIVE_GOAL_FEEDBACK: GoalFeedback,
    Topic.DRIVE_MAP: OccupancyGrid,
    Topic.DRIVE_COSTMAP: OccupancyGrid,
    Topic.DRIVE_PLAN: GoalPlan,
    Topic.RUN_SUMMARY: RunSummary,
}

LATCHED_TOPICS = (
    Topic.SIM_WORLD,
    Topic.DRIVE_PATH,
    Topic.MOTOR_STATE,
    Topic.DRIVE_OUTCOME,
    Topic.DRIVE_GOAL,
    Topic.DRIVE_MAP,
    Topic.DRIVE_PLAN,
)
"""Keys whose publisher also answers queries with its last message (a late viewer gets it at once)."""

BODY_POSE_LENGTH = 12
"""``sim/body_pose``: x, y, z, then the 3x3 rotation matrix row-major."""
SIM_POSE_LENGTH = 4
"""``motor/sim_pose/*``: x, y, z, theta."""


class MethodFamily(StrEnum):
    """The two providers of the Motor interface (the seed's InventGUIProvPort and BumpProvPort)."""

    GUI = "gui"
    BUMP = "bump"


class Method(StrEnum):
    SET_PD_GAIN = "set_pd_gain"
    START = "start"
    FINISH = "finish"
    CLEAR = "clear"
    STOP = "stop"


METHOD_ARGUMENTS: dict[Method, type[msgspec.Struct]] = {
    Method.SET_PD_GAIN: PDGains,
    Method.START: NoArguments,
    Method.FINISH: NoArguments,
    Method.CLEAR: NoArguments,
    Method.STOP: NoArguments,
}


class GoalMethod(StrEnum):
    """The drive's goal queryables (docs/protocol.md section 7.3): ``drive/goal/<method>``."""

    SEND = "send"
    CANCEL = "cancel"


GOAL_METHOD_TYPES: dict[GoalMethod, tuple[type[msgspec.Struct], type[msgspec.Struct]]] = {
    GoalMethod.SEND: (GoalRequest, GoalReply),
    GoalMethod.CANCEL: (CancelRequest, CancelReply),
}
"""Each goal method's payload and reply."""


class LocalizationMethod(StrEnum):
    """The localization's queryables (docs/protocol.md section 7.1): ``localization/<method>``."""

    INITIAL_POSE = "initial_pose"
    GLOBAL_LOCALIZATION = "global_localization"


LOCALIZATION_METHOD_TYPES: dict[LocalizationMethod, tuple[type[msgspec.Struct], type[msgspec.Struct]]] = {
    LocalizationMethod.INITIAL_POSE: (InitialPose, LocalizationReply),
    LocalizationMethod.GLOBAL_LOCALIZATION: (NoArguments, LocalizationReply),
}
"""Each localization method's payload and reply."""


class OdometryMethod(StrEnum):
    """The odometry's queryables (docs/protocol.md section 5): ``odometry/<method>``."""

    SET_POSE = "set_pose"


ODOMETRY_METHOD_TYPES: dict[OdometryMethod, tuple[type[msgspec.Struct], type[msgspec.Struct]]] = {
    OdometryMethod.SET_POSE: (SetOdometry, SetOdometryReply),
}
"""Each odometry method's payload and reply."""
