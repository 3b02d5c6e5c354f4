"""What the bridge is in the ROS graph (pure, no zenoh): its topics, subscriptions, services and its
NavigateToPose action (three services and two topics, as rcl_action lays an action out), with
their interfaces and QoS, and the keys they travel on for a domain and namespace. The bridge
declares exactly these (services/ros2/service.py), and the secure profile grants exactly these
(services/security/grants.py).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

from schemas.topics import Method
from services.config import Config, ConfigError, TfLayout
from services.ros2 import interfaces, wire

DOMAIN_VARIABLE = "ROS_DOMAIN_ID"
MAX_DOMAIN = 232
"""The highest ROS domain id (ROS 2's rule for DDS ports; rmw_zenoh takes the same range)."""


@dataclass(frozen=True)
class Entity:
    name: str
    """Relative to the namespace, or absolute (``/clock``: one for the world, global by ROS convention)."""
    interface: str
    qos: wire.Qos


PUBLICATIONS: dict[str, Entity] = {
    "clock": Entity("/clock", interfaces.CLOCK, wire.CLOCK),
    "odom": Entity("odom", interfaces.ODOMETRY, wire.SYSTEM_DEFAULT),
    "tf": Entity("tf", interfaces.TF_MESSAGE, wire.TF),
    "tf_static": Entity("tf_static", interfaces.TF_MESSAGE, wire.LATCHED),
    "joint_states": Entity("joint_states", interfaces.JOINT_STATE, wire.SYSTEM_DEFAULT),
    "robot_description": Entity("robot_description", interfaces.STRING, wire.LATCHED),
    "scan": Entity("scan", interfaces.LASER_SCAN, wire.SENSOR_DATA),
    "imu": Entity("imu", interfaces.IMU, wire.SENSOR_DATA),
    "map": Entity("map", interfaces.OCCUPANCY_GRID, wire.LATCHED),
    "costmap": Entity("global_costmap/costmap", interfaces.OCCUPANCY_GRID, wire.LATCHED),
    "plan": Entity("plan", interfaces.PATH, wire.PLAN),
}
"""Every topic a bridge may publish, by its short name, but the particle filter's
(:data:`LOCALIZATION_PUBLICATIONS`); :attr:`BridgeGraph.publications` are one bridge's."""
NAVIGATION_TOPICS = ("map", "costmap", "plan")
"""The drive's map, costmap and plan (``drive/map``, ``drive/costmap``, ``drive/plan``), named as
Nav2's map_server, global costmap and planner_server name theirs, in the bridge's namespace. Each is
declared (its publisher and its token) when the drive first publishes its key: a bridge whose robot
has no navigating drive (``--teleop``, a scenario) offers none of them, and leaves the names to a
Nav2 of one's own."""
LOCALIZATION_PUBLICATIONS: dict[str, Entity] = {
    "amcl_pose": Entity("amcl_pose", interfaces.POSE_WITH_COVARIANCE_STAMPED, wire.LATCHED),
    "particle_cloud": Entity("particle_cloud", interfaces.POSE_ARRAY, wire.SENSOR_DATA),
}
LOCALIZATION_TOPICS = tuple(LOCALIZATION_PUBLICATIONS)
"""The particle filter's estimate and particles (``localization/pose`` with a covariance,
``localization/particles``), named and offered as nav2_amcl's: ``amcl_pose``
(geometry_msgs/PoseWithCovarianceStamped, reliable, transient local, keep-last 1) and
``particle_cloud`` (rclcpp's SensorDataQoS; nav2_amcl's type is nav2_msgs/ParticleCloud, which no
typestore here holds: geometry_msgs/PoseArray, what nav2_amcl published before it, docs/ros2.md).
Published only by the bridge of a robot whose ``localization.mode`` is ``amcl``."""
SENSOR_TOPICS = ("scan", "imu")
"""Published only by the bridge of a robot with that sensor (``lidar.enabled``, ``imu.enabled``)."""
TF_TOPICS = ("tf", "tf_static")
"""In the bridge's namespace by default (Nav2's multi-robot layout); on the shared ``/tf`` and
``/tf_static`` with ``ros2.tf = "prefixed"``."""
CMD_VEL_SUBSCRIPTIONS = (
    Entity("cmd_vel", interfaces.TWIST, wire.SYSTEM_DEFAULT),
    Entity("cmd_vel", interfaces.TWIST_STAMPED, wire.SYSTEM_DEFAULT),
)
GOAL_POSE = Entity("goal_pose", interfaces.POSE_STAMPED, wire.SYSTEM_DEFAULT)
"""What RViz's "2D Goal Pose" tool publishes (``/goal_pose``; in the namespace, as ``cmd_vel`` is)."""
INITIAL_POSE = Entity("initialpose", interfaces.POSE_WITH_COVARIANCE_STAMPED, wire.SYSTEM_DEFAULT)
"""What RViz's "2D Pose Estimate" tool publishes (``/initialpose``, in the namespace), subscribed as
nav2_amcl subscribes it (ROS's default QoS), by the bridge of a robot whose localization is ``amcl``:
each becomes a query of ``localization/initial_pose``."""
SUBSCRIPTIONS = (*CMD_VEL_SUBSCRIPTIONS, GOAL_POSE, INITIAL_POSE)
"""Every subscription a bridge may hold (``initialpose`` only with ``localization.mode = "amcl"``)."""
NAVIGATE_TO_POSE = "navigate_to_pose"
"""The NavigateToPose action's name, as Nav2's bt_navigator serves it (in the namespace)."""


class ActionService(StrEnum):
    """An action's services, as rcl_action names them: ``<action>/_action/<service>``."""

    SEND_GOAL = "send_goal"
    CANCEL_GOAL = "cancel_goal"
    GET_RESULT = "get_result"


class ActionTopic(StrEnum):
    """An action's topics, as rcl_action names them: ``<action>/_action/<topic>``."""

    FEEDBACK = "feedback"
    STATUS = "status"


ACTION_SERVICES: dict[ActionService, Entity] = {
    ActionService.SEND_GOAL: Entity(
        f"{NAVIGATE_TO_POSE}/_action/send_goal", interfaces.NAVIGATE_TO_POSE_SEND_GOAL, wire.SERVICES
    ),
    ActionService.CANCEL_GOAL: Entity(f"{NAVIGATE_TO_POSE}/_action/cancel_goal", interfaces.CANCEL_GOAL, wire.SERVICES),
    ActionService.GET_RESULT: Entity(
        f"{NAVIGATE_TO_POSE}/_action/get_result", interfaces.NAVIGATE_TO_POSE_GET_RESULT, wire.SERVICES
    ),
}
"""The NavigateToPose action server's services (rcl_action's services QoS: reliable, volatile, keep-last 10)."""
ACTION_TOPICS: dict[ActionTopic, Entity] = {
    ActionTopic.FEEDBACK: Entity(
        f"{NAVIGATE_TO_POSE}/_action/feedback", interfaces.NAVIGATE_TO_POSE_FEEDBACK_MESSAGE, wire.SYSTEM_DEFAULT
    ),
    ActionTopic.STATUS: Entity(f"{NAVIGATE_TO_POSE}/_action/status", interfaces.GOAL_STATUS_ARRAY, wire.ACTION_STATUS),
}
"""The NavigateToPose action server's topics: feedback as ROS's default QoS, status as rcl_action's
(reliable, transient-local, keep-last 1: a client started late gets the last status)."""
MOTOR_SERVICES: dict[Method, Entity] = {
    method: Entity(f"motor/{method}", interfaces.TRIGGER, wire.SERVICES)
    for method in (Method.STOP, Method.CLEAR, Method.START, Method.FINISH)
}
"""The Motor methods ROS calls, as std_srvs/Trigger services (``set_pd_gain`` takes arguments Trigger has not)."""


class OdometryService(StrEnum):
    """The odometry services ros2_controllers offers, private names of the bridge's node (``~/``)."""

    RESET = "reset_odometry"
    """ros2_controllers' (tricycle_controller's) reset: the pose (0, 0, 0)."""
    SET = "set_odometry"
    """diff_drive_controller's: the pose given (x, y, yaw)."""


ODOMETRY_SERVICE_TYPES: dict[OdometryService, str] = {
    OdometryService.RESET: interfaces.EMPTY,
    OdometryService.SET: interfaces.SET_ODOMETRY,
}


@dataclass(frozen=True)
class BridgeGraph:
    """The bridge's node and entities in one ROS domain and namespace."""

    domain: int
    namespace: str
    """``""`` or absolute (:func:`wire.absolute_namespace`)."""
    node_name: str
    type_hashes: bool = True
    """False for Humble, whose rmw_zenoh writes ``TypeHashNotSupported`` in place of the hash."""
    tf_shared: bool = False
    """``ros2.tf = "prefixed"``: TF on the shared ``/tf`` and ``/tf_static`` (else in the namespace)."""
    publishes_clock: bool = True
    sensors: frozenset[str] = frozenset(SENSOR_TOPICS)
    """Of :data:`SENSOR_TOPICS`, those of the sensors the robot has."""
    localization: bool = False
    """``localization.mode = "amcl"``: :data:`LOCALIZATION_TOPICS` published, :data:`INITIAL_POSE` subscribed."""
    publishes_tf: bool = True
    """Whether any of ``odom -> base_link``, ``map -> odom`` and the wheels goes on ``tf``
    (``ros2.enable_odom_tf``, ``enable_map_odom_tf``, ``enable_wheel_tf``); none: no ``tf`` publisher."""
    navigate_to_pose: bool = True
    """``ros2.navigate_to_pose``: the action (:data:`ACTION_SERVICES`, :data:`ACTION_TOPICS`) served
    and :data:`GOAL_POSE` subscribed; off, neither declared."""

    @property
    def publications(self) -> dict[str, Entity]:
        """What this bridge publishes: :data:`PUBLICATIONS`, its TF topics where ``ros2.tf`` puts
        them (``tf`` only if it carries a transform), ``/clock`` only if it publishes it, ``scan`` and ``imu`` only for the sensors the robot has,
        :data:`NAVIGATION_TOPICS` (declared once the drive publishes what they come from), and
        :data:`LOCALIZATION_TOPICS` only with the particle filter."""
        entities = {}
        offered = {**PUBLICATIONS, **(LOCALIZATION_PUBLICATIONS if self.localization else {})}
        for topic, entity in offered.items():
            if (
                (topic == "clock" and not self.publishes_clock)
                or (topic in SENSOR_TOPICS and topic not in self.sensors)
                or (topic == "tf" and not self.publishes_tf)
            ):
                continue
            shared = topic in TF_TOPICS and self.tf_shared
            entities[topic] = dataclasses.replace(entity, name=f"/{entity.name}") if shared else entity
        return entities

    @property
    def subscriptions(self) -> tuple[Entity, ...]:
        """What this bridge subscribes: :data:`SUBSCRIPTIONS`, ``initialpose`` only with the particle
        filter, ``goal_pose`` only with the action."""
        return tuple(
            entity
            for entity in SUBSCRIPTIONS
            if (entity is not INITIAL_POSE or self.localization) and (entity is not GOAL_POSE or self.navigate_to_pose)
        )

    @property
    def odometry_services(self) -> dict[OdometryService, Entity]:
        """``~/reset_odometry`` and ``~/set_odometry``: under the node's name, in its namespace
        (``/invent_bridge/set_odometry``), as rclcpp expands ``~``."""
        return {
            service: Entity(f"{self.node_name}/{service}", interface, wire.SERVICES)
            for service, interface in ODOMETRY_SERVICE_TYPES.items()
        }

    @property
    def frame_prefix(self) -> str:
        """What the robot's frames are prefixed with: ``rh0/`` on a shared ``/tf``, else nothing."""
        stripped = self.namespace.strip("/")
        return f"{stripped}/" if self.tf_shared and stripped else ""

    def name(self, entity: Entity) -> str:
        return wire.full_name(self.namespace, entity.name)

    def type_hash(self, entity: Entity) -> str:
        return interfaces.interface(entity.interface).type_hash if self.type_hashes else wire.TYPE_HASH_NOT_SUPPORTED

    def key(self, entity: Entity) -> str:
        return wire.data_key(self.domain, self.name(entity), entity.interface, self.type_hash(entity))

    @property
    def node_tokens(self) -> tuple[str, str]:
        """Key expressions of the node's token and of its entities' tokens, for any session id."""
        node = f"{wire.ADMIN_SPACE}/{self.domain}/*/*/*/*/*/{wire.mangle(self.namespace)}/{self.node_name}"
        return node, f"{node}/**"


def ros_domain(environ: Mapping[str, str] = os.environ) -> int:
    """``$ROS_DOMAIN_ID`` (default 0); ConfigError naming it when it is not 0..232."""
    text = environ.get(DOMAIN_VARIABLE, "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > MAX_DOMAIN:
        raise ConfigError(f"${DOMAIN_VARIABLE}={text!r}: a ROS domain id is a whole number 0..{MAX_DOMAIN}")
    return int(text)


def bridge_graph(config: Config, environ: Mapping[str, str] = os.environ) -> BridgeGraph:
    """The bridge of ``config`` (``[ros2]``) in the domain of ``$ROS_DOMAIN_ID``."""
    settings = config.ros2
    return BridgeGraph(
        ros_domain(environ),
        wire.absolute_namespace(settings.namespace),
        settings.node_name,
        type_hashes=settings.distro != "humble",
        tf_shared=settings.tf is TfLayout.PREFIXED,
        publishes_clock=settings.publish_clock,
        sensors=frozenset(
            topic for topic, enabled in zip(SENSOR_TOPICS, (config.lidar.enabled, config.imu.enabled)) if enabled
        ),
        localization=config.localization.mode == "amcl",
        publishes_tf=settings.enable_odom_tf or settings.enable_map_odom_tf or settings.enable_wheel_tf,
        navigate_to_pose=settings.navigate_to_pose,
    )
