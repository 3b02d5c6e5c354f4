"""The key space of docs/protocol.md section 2, as one function of the robot name.

No key string is spelled anywhere else: services, tools and tests build every key from
:class:`Keys`, and :func:`schema_for_key` maps a concrete key back to its message type.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import StrEnum
from typing import NewType, TypeAlias

from schemas.topics import (
    TOPIC_TYPES,
    GoalMethod,
    LocalizationMethod,
    Method,
    MethodFamily,
    OdometryMethod,
    Topic,
    TopicMessage,
)

ROOT = "invent"
DEFAULT_ROBOT = "rh0"
_ROBOT_NAME = re.compile(r"[A-Za-z0-9_\-.]+")


class Service(StrEnum):
    MOTOR = "motor"
    ODOMETRY = "odometry"
    SIM = "sim"
    LOCALIZATION = "localization"
    DRIVE = "drive"
    ROS2 = "ros2"
    """The ROS 2 bridge (``invent ros2``): not part of the loop; its ROS keys are outside ``invent/``."""


LOOP_SERVICES = tuple(service for service in Service if service is not Service.ROS2)
"""The services of the closed loop that ``invent up`` always runs (every one but the ROS 2 bridge)."""

UserServiceName = NewType("UserServiceName", str)
"""The name of a service of one's own (services/extension/, docs/extending.md): one key chunk,
never a built-in's; made only by :func:`user_service_name`, which checks it."""
ServiceName: TypeAlias = Service | UserServiceName
"""Whose keys: a built-in service, or a user service (``invent/<robot>/<name>/...``)."""
_USER_SERVICE_NAME = re.compile(r"[a-z][a-z0-9_]{0,31}")
RESERVED_NAMES = frozenset(
    {"up", "view", "router", "all", "ros", "invent", "operator", "observer", "ros_node", "control"}
)
"""Chunks a user service may not take beside the built-ins': ``up/run``, ``view/status``,
``control/status``, the secure profile's other users (a user service's credentials are
``<name>.json5`` beside theirs), and names the command line or the tools use for themselves."""


_STATUS = "status"
VIEW = "view"
CONTROL = "control"
ALIVE = "alive"
TICKS = "ticks"
OBSERVES = "observes"


def user_service_name(name: str) -> UserServiceName:
    """``name`` as a user service's name: lower case letters, digits and ``_``, starting with a
    letter, at most 32 characters, neither a built-in service's name nor reserved
    (:data:`RESERVED_NAMES`); ValueError saying which rule it breaks."""
    if not _USER_SERVICE_NAME.fullmatch(name):
        raise ValueError(f"service name {name!r} must match {_USER_SERVICE_NAME.pattern} (one key chunk)")
    if name in Service._value2member_map_:
        raise ValueError(f"service name {name!r} is a built-in service's")
    if name in RESERVED_NAMES:
        raise ValueError(f"service name {name!r} is reserved ({', '.join(sorted(RESERVED_NAMES))})")
    return UserServiceName(name)


def service_name(name: str) -> ServiceName:
    """A built-in :class:`Service` for its name, else ``name`` as a user service's (ValueError if not one)."""
    return Service(name) if name in Service._value2member_map_ else user_service_name(name)


def validate_robot_name(name: str) -> str:
    """Return ``name`` if it is one key chunk (no ``/``, wildcards or spaces), else raise ValueError."""
    if not _ROBOT_NAME.fullmatch(name):
        raise ValueError(f"robot name {name!r} must match {_ROBOT_NAME.pattern}")
    return name


@dataclass(frozen=True)
class Keys:
    """Every key of one robot. ``Keys("rh0").motor_torque == "invent/rh0/motor/torque"``."""

    robot: str = DEFAULT_ROBOT

    def __post_init__(self) -> None:
        validate_robot_name(self.robot)

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.robot}"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"

    def topic(self, topic: Topic) -> str:
        return f"{self.prefix}/{topic}"

    def method(self, family: MethodFamily, method: Method) -> str:
        return f"{self.prefix}/{Service.MOTOR}/{family}/{method}"

    def goal_method(self, method: GoalMethod) -> str:
        """``invent/<robot>/drive/goal/send`` or ``.../cancel``: the drive's goal queryables."""
        return f"{self.prefix}/{Topic.DRIVE_GOAL}/{method}"

    def localization_method(self, method: LocalizationMethod) -> str:
        """``invent/<robot>/localization/initial_pose`` or ``.../global_localization``."""
        return f"{self.prefix}/{Service.LOCALIZATION}/{method}"

    def odometry_method(self, method: OdometryMethod) -> str:
        """``invent/<robot>/odometry/set_pose``."""
        return f"{self.prefix}/{Service.ODOMETRY}/{method}"

    def status(self, service: ServiceName) -> str:
        return f"{self.prefix}/{service}/{_STATUS}"

    @property
    def view_status(self) -> str:
        """The status of ``invent view`` (a tool, not a service of the loop)."""
        return f"{self.prefix}/{VIEW}/{_STATUS}"

    @property
    def control_status(self) -> str:
        """The status of ``invent control``'s process (the sim and the motor composed), beside theirs."""
        return f"{self.prefix}/{CONTROL}/{_STATUS}"

    def under(self, service: ServiceName) -> str:
        """Key expression matching every key under ``service``'s name (``invent/<robot>/drive/**``):
        one subscriber for several of its keys gets their samples in the order they were published
        (zenoh runs the callbacks of two subscribers in no set order)."""
        return f"{self.prefix}/{service}/**"

    @property
    def every_status(self) -> str:
        """Key expression matching the ``status`` queryable of every service of this robot."""
        return f"{self.prefix}/*/{_STATUS}"

    @property
    def every_alive(self) -> str:
        """Key expression matching the liveliness token of every service of this robot."""
        return f"{self.prefix}/*/{ALIVE}"

    def alive(self, service: ServiceName) -> str:
        """The liveliness token a running service holds."""
        return f"{self.prefix}/{service}/{ALIVE}"

    def ticks(self, service: ServiceName, rate_hz: float) -> str:
        """The liveliness token of a lockstep participant: ``service`` outputs on a grid of
        ``rate_hz`` ticks per second of simulation time (services/clock/lockstep.py)."""
        return f"{self.prefix}/{service}/{TICKS}/{rate_hz!r}"

    def ticks_with_output(self, service: UserServiceName, rate_hz: float, output: str) -> str:
        """A user service's participant token: :meth:`ticks` followed by its output's key under its
        own name (``invent/rh0/odometer/ticks/10.0/distance`` waits for ``odometer/distance``), so the
        simulator learns what to wait for from the token itself (:func:`parse_participant_key`)."""
        return f"{self.ticks(service, rate_hz)}/{validate_own_key(output)}"

    def own(self, service: ServiceName, suffix: str) -> str:
        """A key under ``service``'s own name: ``own("odometer", "distance")`` ==
        ``invent/<robot>/odometer/distance`` (ValueError for a suffix that cannot be one: :func:`validate_own_key`)."""
        return f"{self.prefix}/{service}/{validate_own_key(suffix)}"

    def ticks_at_any_rate(self, service: ServiceName) -> str:
        """Key expression matching ``service``'s lockstep participant token, whatever its rate (and,
        a user service's, its output)."""
        return f"{self.prefix}/{service}/{TICKS}/{'*' if isinstance(service, Service) else '**'}"

    @property
    def every_ticks(self) -> str:
        """Key expression matching every lockstep participant's token of this robot (a user
        participant's names its output after its rate: ``**``)."""
        return f"{self.prefix}/*/{TICKS}/**"

    def observes(self, service: ServiceName, rate_hz: float) -> str:
        """The liveliness token of an observer: ``service`` takes what the loop observes (the
        simulation clock, poses) ``rate_hz`` times per second of simulation time, on the same grid
        as a participant's ticks, so the simulator marks those steps observed (docs/protocol.md
        section 2.7) without waiting for anything."""
        return f"{self.prefix}/{service}/{OBSERVES}/{rate_hz!r}"

    def observes_at_any_rate(self, service: ServiceName) -> str:
        """Key expression matching ``service``'s observer tokens, whatever their rates."""
        return f"{self.prefix}/{service}/{OBSERVES}/*"

    @property
    def every_observes(self) -> str:
        """Key expression matching every observer's token of this robot."""
        return f"{self.prefix}/*/{OBSERVES}/*"

    sim_wheel_angles = property(lambda self: self.topic(Topic.SIM_WHEEL_ANGLES))
    sim_clock = property(lambda self: self.topic(Topic.SIM_CLOCK))
    sim_body_pose = property(lambda self: self.topic(Topic.SIM_BODY_POSE))
    sim_bump = property(lambda self: self.topic(Topic.SIM_BUMP))
    sim_scan = property(lambda self: self.topic(Topic.SIM_SCAN))
    sim_imu = property(lambda self: self.topic(Topic.SIM_IMU))
    motor_torque = property(lambda self: self.topic(Topic.MOTOR_TORQUE))
    motor_wheel_velocity = property(lambda self: self.topic(Topic.MOTOR_WHEEL_VELOCITY))
    motor_wheel_angles = property(lambda self: self.topic(Topic.MOTOR_WHEEL_ANGLES))
    motor_sim_pose_gui = property(lambda self: self.topic(Topic.MOTOR_SIM_POSE_GUI))
    motor_sim_pose_localization = property(lambda self: self.topic(Topic.MOTOR_SIM_POSE_LOCALIZATION))
    drive_target_velocity = property(lambda self: self.topic(Topic.DRIVE_TARGET_VELOCITY))
    odometry_pose = property(lambda self: self.topic(Topic.ODOMETRY_POSE))
    odometry_set_pose = property(lambda self: self.odometry_method(OdometryMethod.SET_POSE))
    localization_pose = property(lambda self: self.topic(Topic.LOCALIZATION_POSE))
    localization_particles = property(lambda self: self.topic(Topic.LOCALIZATION_PARTICLES))
    localization_initial_pose = property(lambda self: self.localization_method(LocalizationMethod.INITIAL_POSE))
    localization_global_localization = property(
        lambda self: self.localization_method(LocalizationMethod.GLOBAL_LOCALIZATION)
    )
    sim_world = property(lambda self: self.topic(Topic.SIM_WORLD))
    drive_path = property(lambda self: self.topic(Topic.DRIVE_PATH))
    motor_state = property(lambda self: self.topic(Topic.MOTOR_STATE))
    drive_outcome = property(lambda self: self.topic(Topic.DRIVE_OUTCOME))
    drive_goal = property(lambda self: self.topic(Topic.DRIVE_GOAL))
    drive_goal_feedback = property(lambda self: self.topic(Topic.DRIVE_GOAL_FEEDBACK))
    drive_map = property(lambda self: self.topic(Topic.DRIVE_MAP))
    drive_costmap = property(lambda self: self.topic(Topic.DRIVE_COSTMAP))
    drive_plan = property(lambda self: self.topic(Topic.DRIVE_PLAN))
    drive_goal_send = property(lambda self: self.goal_method(GoalMethod.SEND))
    drive_goal_cancel = property(lambda self: self.goal_method(GoalMethod.CANCEL))
    run_summary = property(lambda self: self.topic(Topic.RUN_SUMMARY))


def all_robots_alive() -> str:
    """Key expression matching the liveliness token of every service of every robot."""
    return f"{ROOT}/*/*/{ALIVE}"


def all_robots_status() -> str:
    return f"{ROOT}/*/*/{_STATUS}"


_OWN_CHUNK = re.compile(r"[A-Za-z0-9_\-.]+")
_SERVICE_CHUNKS = frozenset({_STATUS, ALIVE, TICKS, OBSERVES})


def own_suffix_error(suffix: str) -> str | None:
    """Why ``suffix`` cannot be a key under a service's name, or None when it can."""
    chunks = suffix.split("/")
    for chunk in chunks:
        if not _OWN_CHUNK.fullmatch(chunk):
            return f"key {suffix!r}: each chunk must match {_OWN_CHUNK.pattern} (no wildcards, no empty chunk)"
    if chunks[0] in _SERVICE_CHUNKS:
        return f"key {suffix!r}: {chunks[0]!r} is the runtime's own (status, alive, ticks, observes)"
    return None


def validate_own_key(suffix: str) -> str:
    """``suffix`` (``distance``, ``progress/leg``) if it may name a key under a service's own name,
    else ValueError saying why."""
    error = own_suffix_error(suffix)
    if error is not None:
        raise ValueError(error)
    return suffix


def parse_data_key(key: str) -> tuple[str, Topic] | None:
    """(robot, topic) of a concrete data key, or None when ``key`` is not one."""
    parts = key.split("/", 2)
    if len(parts) != 3 or parts[0] != ROOT or parts[2] not in Topic._value2member_map_:
        return None
    return parts[1], Topic(parts[2])


def parse_status_key(key: str) -> tuple[str, str] | None:
    """(robot, name) of a concrete status key, ``invent/<robot>/<name>/status`` (a service's, or
    ``view``'s or ``control``'s), or None when ``key`` is not one."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[3] != _STATUS or not parts[1] or not parts[2]:
        return None
    return parts[1], parts[2]


def schema_for_key(key: str) -> type[TopicMessage] | None:
    """The message type a concrete data key carries, or None when the key is not a data key."""
    parsed = parse_data_key(key)
    return None if parsed is None else TOPIC_TYPES[parsed[1]]
