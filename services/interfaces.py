"""What each built-in service takes and gives (:class:`schemas.interface.Interface`), declared once.

The graph of the stack as data, as a dora dataflow or a ROS launch file's remappings: each
service's node refuses a key that is not here (services/runtime/node.py), and the roles' grants
(services/security/grants.py), the launcher's liveliness waits, the recording's channels and the
loop diagram of docs/architecture.md (:mod:`services.interfaces_diagram`) are made from it. Keys
outside ``invent/`` (the ROS 2 bridge's ROS graph) are declared by :mod:`services.ros2.graph`.
"""

from __future__ import annotations

from schemas.interface import Interface, Participation
from schemas.keys import LOOP_SERVICES, Keys, Service
from schemas.topics import GoalMethod, LocalizationMethod, Method, MethodFamily, Topic
from services.clock.lockstep import OUTPUTS
from services.config import Config
from services.config.sections import LocalizationMode
from services.ros2.graph import MOTOR_SERVICES, BridgeGraph, bridge_graph


def _topics(keys: Keys, *topics: Topic) -> tuple[str, ...]:
    return tuple(keys.topic(topic) for topic in topics)


def _motor_methods(keys: Keys, *families: MethodFamily) -> tuple[str, ...]:
    return tuple(keys.method(family, method) for family in families for method in Method)


def sim(keys: Keys, _config: Config) -> Interface:
    """The simulator: its sensors and clock out, the control path's output in, the lockstep
    participants' outputs (only their stamps), the bump stop asked of the motor, and each
    participant's status at the start (has it seen this simulator?)."""
    return Interface(
        Service.SIM,
        publishes=_topics(
            keys,
            Topic.SIM_BODY_POSE,
            Topic.SIM_WHEEL_ANGLES,
            Topic.SIM_CLOCK,
            Topic.SIM_BUMP,
            Topic.SIM_SCAN,
            Topic.SIM_IMU,
            Topic.SIM_WORLD,
        ),
        subscribes=_topics(keys, Topic.MOTOR_TORQUE, Topic.MOTOR_WHEEL_VELOCITY, *OUTPUTS.values()),
        queries=(
            keys.method(MethodFamily.BUMP, Method.STOP),
            *(keys.status(service) for service in (Service.MOTOR, *OUTPUTS)),
        ),
        follows_participants=True,
    )


def motor(keys: Keys, _config: Config) -> Interface:
    """The motor: the seed's MotorControlRTC, with its collision monitor's scans and both outputs
    (torque, or wheel velocities through the velocity seam)."""
    return Interface(
        Service.MOTOR,
        publishes=_topics(
            keys,
            Topic.MOTOR_STATE,
            Topic.MOTOR_TORQUE,
            Topic.MOTOR_WHEEL_VELOCITY,
            Topic.MOTOR_WHEEL_ANGLES,
            Topic.MOTOR_SIM_POSE_GUI,
            Topic.MOTOR_SIM_POSE_LOCALIZATION,
        ),
        subscribes=_topics(
            keys, Topic.SIM_WHEEL_ANGLES, Topic.SIM_BODY_POSE, Topic.DRIVE_TARGET_VELOCITY, Topic.SIM_SCAN
        ),
        serves=_motor_methods(keys, MethodFamily.GUI, MethodFamily.BUMP),
    )


def odometry(keys: Keys, _config: Config) -> Interface:
    return Interface(
        Service.ODOMETRY,
        publishes=_topics(keys, Topic.ODOMETRY_POSE),
        subscribes=_topics(keys, Topic.MOTOR_WHEEL_ANGLES, Topic.LOCALIZATION_POSE),
        serves=(keys.odometry_set_pose,),
    )


def localization(keys: Keys, config: Config) -> Interface:
    """In its ``localization.mode``: the stub reads the ground truth the motor hands it; amcl reads
    the lidar and the wheels (and serves where the robot is); none only the wheels, and takes no
    part in lockstep (one pose at the start)."""
    return localization_in(keys, config.localization.mode, config.localization.rate)


def localization_in(keys: Keys, mode: LocalizationMode, rate_hz: float) -> Interface:
    """:func:`localization` in ``mode``, its fixes at ``rate_hz``."""
    fix = Participation(rate_hz, keys.localization_pose)
    if mode == "amcl":
        return Interface(
            Service.LOCALIZATION,
            publishes=_topics(keys, Topic.LOCALIZATION_POSE, Topic.LOCALIZATION_PARTICLES),
            subscribes=_topics(keys, Topic.SIM_SCAN, Topic.MOTOR_WHEEL_ANGLES),
            serves=tuple(keys.localization_method(method) for method in LocalizationMethod),
            participates=fix,
        )
    if mode == "none":
        return Interface(
            Service.LOCALIZATION,
            publishes=_topics(keys, Topic.LOCALIZATION_POSE),
            subscribes=_topics(keys, Topic.MOTOR_WHEEL_ANGLES),
        )
    return Interface(
        Service.LOCALIZATION,
        publishes=_topics(keys, Topic.LOCALIZATION_POSE),
        subscribes=_topics(keys, Topic.MOTOR_SIM_POSE_LOCALIZATION),
        participates=fix,
    )


def drive(keys: Keys, config: Config, rate_hz: float | None = None) -> Interface:
    """The drive, in either mode: scenarios, or goals (served, with their feedback and outcome)
    navigated on the map, the costmap of its lidar and the planner's plan; its ticks at
    ``drive.rate``, or ``rate_hz`` (a service of one's own that drives in its place, as the drive)."""
    return Interface(
        Service.DRIVE,
        publishes=_topics(
            keys,
            Topic.DRIVE_TARGET_VELOCITY,
            Topic.DRIVE_PATH,
            Topic.DRIVE_OUTCOME,
            Topic.DRIVE_GOAL,
            Topic.DRIVE_GOAL_FEEDBACK,
            Topic.DRIVE_MAP,
            Topic.DRIVE_COSTMAP,
            Topic.DRIVE_PLAN,
        ),
        subscribes=_topics(
            keys, Topic.MOTOR_STATE, Topic.SIM_BUMP, Topic.SIM_CLOCK, Topic.ODOMETRY_POSE, Topic.SIM_SCAN
        ),
        serves=tuple(keys.goal_method(method) for method in GoalMethod),
        queries=(keys.motor_state,),
        participates=Participation(config.drive.rate if rate_hz is None else rate_hz, keys.drive_target_velocity),
    )


def ros2(keys: Keys, config: Config, ros: BridgeGraph | None = None) -> Interface:
    """The ROS 2 bridge's side in ``invent/`` (its ROS side: :class:`services.ros2.graph.BridgeGraph`,
    ``ros``, by default the one ``config`` describes): what it turns into ROS topics, the twists
    and calls it forwards, and its observer tokens (``/clock`` and the poses at their rates)."""
    graph = bridge_graph(config) if ros is None else ros
    settings = config.ros2
    sensors = {"scan": Topic.SIM_SCAN, "imu": Topic.SIM_IMU}
    subscribed = [Topic.SIM_CLOCK, Topic.ODOMETRY_POSE, Topic.MOTOR_TORQUE]
    subscribed += [topic for name, topic in sensors.items() if name in graph.sensors]
    subscribed += [Topic.DRIVE_MAP, Topic.DRIVE_PLAN, Topic.DRIVE_COSTMAP]
    queries = [keys.method(MethodFamily.GUI, method) for method in MOTOR_SERVICES]
    queries += [keys.drive_map, keys.drive_plan]  # latched: their last message when it starts
    if graph.localization:
        subscribed += [Topic.LOCALIZATION_POSE, Topic.LOCALIZATION_PARTICLES]
        queries.append(keys.localization_initial_pose)
    if graph.navigate_to_pose:
        subscribed += [Topic.DRIVE_GOAL, Topic.DRIVE_GOAL_FEEDBACK, Topic.DRIVE_OUTCOME]
        queries += [keys.goal_method(method) for method in GoalMethod]
    rates = {settings.publish_rate, *((settings.clock_rate,) if graph.publishes_clock else ())}
    return Interface(
        Service.ROS2,
        publishes=_topics(keys, Topic.DRIVE_TARGET_VELOCITY),
        subscribes=_topics(keys, *subscribed),
        queries=tuple(queries),
        observes=tuple(sorted(rates)),
    )


DECLARED = {
    Service.SIM: sim,
    Service.MOTOR: motor,
    Service.ODOMETRY: odometry,
    Service.LOCALIZATION: localization,
    Service.DRIVE: drive,
    Service.ROS2: ros2,
}
"""Each built-in service's declaration."""


def declared(service: Service, keys: Keys, config: Config) -> Interface:
    """What ``service`` of the robot ``keys.robot``, described by ``config``, takes and gives."""
    return DECLARED[service](keys, config)


def loop(keys: Keys, config: Config) -> tuple[Interface, ...]:
    """The closed loop's services (every one ``invent up`` always runs), in :data:`LOOP_SERVICES`' order."""
    return tuple(declared(service, keys, config) for service in LOOP_SERVICES)


def participants(keys: Keys, config: Config, drive_rate_hz: float | None = None) -> tuple[Interface, ...]:
    """The loop's lockstep participants (the simulator waits for their outputs at their ticks): the
    drive (ticking at ``drive_rate_hz`` when a service of one's own drives in its place) and a
    localization that takes part."""
    ticking = (drive(keys, config, drive_rate_hz), localization(keys, config))
    return tuple(interface for interface in ticking if interface.participates is not None)


def published(keys: Keys, config: Config) -> tuple[str, ...]:
    """Every key the closed loop's services publish, in the order they declare them: a recording's
    channels (services/recording/mcap_files.py)."""
    return tuple(dict.fromkeys(key for interface in loop(keys, config) for key in interface.publishes))
