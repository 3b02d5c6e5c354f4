"""The robot description: one TOML file, a shared ``[robot]`` table and one table per service.

Defaults are the seeds' (docs/protocol.md section 3); every default lives here and nowhere else.
Loading is typed and strict (msgspec): an unknown key, a wrong type or a value out of range
raises :class:`ConfigError` naming the field, and the CLI exits with code 2.
"""

from __future__ import annotations

import copy
import functools
import json
import math
import re
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple, TypeVar

import msgspec

from schemas.keys import DEFAULT_ROBOT, validate_robot_name
from schemas.messages import NANOSECONDS_PER_SECOND

Positive = Annotated[float, msgspec.Meta(gt=0.0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0)]
WheelId = Annotated[int, msgspec.Meta(ge=0)]


NONE = "none"
"""How a file or ``--set`` turns off an optional parameter (a motor limit, the localization's seed,
the sim's world): TOML has no null, so ``max_vx = "none"`` or ``--set motor.max_vx=none`` is None."""


class ConfigError(ValueError):
    """An invalid configuration file, value or override; the message names the field."""


class _Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    def __post_init__(self) -> None:
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                hint = f' (write "{NONE}" to turn it off)' if name in optional_fields(type(self)) else ""
                raise ValueError(f"`{name}` must be finite, got {value}{hint}")


@functools.cache
def optional_fields(section: type[msgspec.Struct]) -> frozenset[str]:
    """The fields of ``section`` that may be None (written :data:`NONE` in a file or ``--set``)."""
    return frozenset(
        field.name
        for field in msgspec.inspect.type_info(section).fields  # type: ignore[attr-defined]
        if isinstance(field.type, msgspec.inspect.UnionType)
        and any(isinstance(member, msgspec.inspect.NoneType) for member in field.type.types)
    )


class RobotConfig(_Section, frozen=True):
    """Geometry shared by every service (the seeds duplicated it in each ``.conf``)."""

    name: str = DEFAULT_ROBOT
    left_wheel_id: WheelId = 0
    right_wheel_id: WheelId = 1
    radius_of_left_wheel: Positive = 0.1
    radius_of_right_wheel: Positive = 0.1
    length_of_axle: Positive = 0.441
    radius_of_body_area: Positive = 0.45

    def __post_init__(self) -> None:
        super().__post_init__()
        validate_robot_name(self.name)
        if self.left_wheel_id == self.right_wheel_id:
            raise ValueError("`right_wheel_id` must differ from `left_wheel_id`")

    @property
    def half_axle(self) -> float:
        return self.length_of_axle / 2.0


class TargetAngleMode(StrEnum):
    """``seed``: q_ref restarts from the measured angle each cycle (docs/protocol.md section 4 step 3); ``integrated``:
    q_ref accumulates from the previous target angle, so the P term corrects drift (docs/motor.md)."""

    SEED = "seed"
    INTEGRATED = "integrated"


class MotorConfig(_Section, frozen=True):
    p_gain_l: NonNegative = 5.0
    """P gain of the left wheel (the seed's PGainL); changeable at run time with set_pd_gain."""
    p_gain_r: NonNegative = 5.0
    """P gain of the right wheel (PGainR)."""
    d_gain_l: NonNegative = 2.0
    """D gain of the left wheel (DGainL)."""
    d_gain_r: NonNegative = 2.0
    """D gain of the right wheel (DGainR)."""
    simulated_offset_x: float = 0.0
    """m, model origin -> axle centre along the model's x (SimulatedOffsetX); locked at start."""
    simulated_offset_y: float = 0.0
    """m, model origin -> axle centre along the model's y (SimulatedOffsetY; RH0: 0.045795)."""
    simulated_offset_angle: float = 0.0
    """rad, heading of the model's zero direction from +x (SimulatedOffsetAngle; RH0: 1.5708)."""
    command_timeout: NonNegative = 0.5
    """Seconds of wheel-angle time without a target velocity before braking to zero; 0 disables."""
    target_angle: TargetAngleMode = TargetAngleMode.SEED
    """How the target wheel angle is formed (see TargetAngleMode)."""
    max_vx: Positive | None = 1.0
    """Limit on |vx| in m/s (as ros2's diff_drive_controller users expect); None (``"none"`` in a
    file or ``--set``) = no limit, the seed's behaviour. The defaults fit the default robot and sit
    above what the drive commands."""
    max_ax: Positive | None = 2.0
    """Limit on the rate of change of vx in m/s^2 (a step in wheel speed slips: docs/motor.md)."""
    max_w: Positive | None = 3.0
    """Limit on |w| in rad/s."""
    max_aw: Positive | None = 8.0
    """Limit on the rate of change of w in rad/s^2."""


StraightStep = Literal["exact", "seed"]
"""ΔL of the straight and rho_border branches: ``exact``, the step's own mean wheel travel
(r_L·Δq_L + r_R·Δq_R)/2; ``seed``, the seed's trapezoid (V + V_old)/2·Δt (docs/odometry.md)."""


class OdometryConfig(_Section, frozen=True):
    initial_x: float = 0.0
    """The pose the odometry starts from, before any fix: x in m (a fleet sets it to the robot's start)."""
    initial_y: float = 0.0
    """Starting pose: y in m."""
    initial_theta: float = 0.0
    """Starting pose: heading in rad."""
    rotation_angle_border: Positive = math.pi / 180.0
    """|dphi| below which a step takes arc length for chord (the seed's RotationAngleBorder), rad."""
    rho_border: Positive = 10000.0
    """|rho| above which a step integrates as straight, rho clamped (the seed's RhoBorder), m."""
    left_radius_scale: Positive = 1.0
    """Calibration multiplier on the left wheel radius (docs/protocol.md section 9.6: 1.0 = no calibration)."""
    right_radius_scale: Positive = 1.0
    """Calibration multiplier on the right wheel radius (1.0 = no calibration)."""
    axle_scale: Positive = 1.0
    """Calibration multiplier on the axle length (1.0 = no calibration)."""
    straight_step: StraightStep = "exact"
    """How the straight and rho_border branches integrate (see StraightStep)."""


class CalibratedGeometry(NamedTuple):
    """The lengths the odometry integrates with and the motor turns body velocities into wheel
    speeds with: the robot's, times the calibration multipliers of ``[odometry]`` (as ROS 2's
    diff_drive_controller applies its multipliers to both; docs/odometry.md, Calibration)."""

    left_radius: float
    """r_L: the configured radius times its calibration multiplier."""
    right_radius: float
    half_axle: float
    """b = calibrated axle length / 2."""

    @classmethod
    def of(cls, robot: RobotConfig, odometry: OdometryConfig) -> CalibratedGeometry:
        return cls(
            robot.radius_of_left_wheel * odometry.left_radius_scale,
            robot.radius_of_right_wheel * odometry.right_radius_scale,
            robot.length_of_axle * odometry.axle_scale / 2.0,
        )


class SimMode(StrEnum):
    """``lockstep``: every step waits for its torque; ``realtime``: steps paced to the wall clock
    (docs/protocol.md section 6)."""

    LOCKSTEP = "lockstep"
    REALTIME = "realtime"


class SimConfig(_Section, frozen=True):
    mode: SimMode = SimMode.LOCKSTEP
    step: Positive = 0.001
    """Simulated seconds per physics step."""
    observe_every: Annotated[int, msgspec.Meta(ge=1)] = 20
    """Steps between two observed steps, beside every lockstep participant's tick: the steps at
    which what is observed rather than controlled goes out (``sim/clock``, ``sim/body_pose``,
    the motor's simulated poses, ``odometry/pose``; docs/protocol.md section 2.7). 1 = every
    step, the seeds' every-cycle behaviour. A recorded run records every step all the same."""
    lockstep_timeout: Positive = 0.5
    """Wall seconds a lockstep step waits for its torque before applying zero and going on."""
    lockstep_max_late: Annotated[int, msgspec.Meta(ge=1)] = 3
    """Late torques in a row after which lockstep steps at real-time pace until the motor control answers again."""
    realtime_factor: Positive = 1.0
    """Realtime mode: simulated seconds per wall second."""
    torque_max_age: Positive = 0.01
    """Realtime mode: simulated seconds after which the newest torque is stale (zero is applied)."""
    brake_after: Positive | None = 0.5
    """Simulated seconds without a torque from the robot's motor control (gone, silent, or cut off
    by a link down) after which the simulated motor driver brakes the wheels (to rest, at most
    ``max_wheel_torque``) until a torque comes again, as a driver's watchdog does; the default is
    the motor's own ``command_timeout``. None (``"none"``): the wheels run free on zero torque."""
    world: str | None = None
    """World file (TOML) or built-in world name (sim_bridge/worlds/); None (``"none"``) = an empty floor."""
    body_mass: Positive = 20.0
    """kg; the body's centre of mass sits on the axle centre."""
    body_height: Positive = 0.15
    """m; the body is a cylinder of radius robot.radius_of_body_area whose bottom is at axle height."""
    wheel_mass: Positive = 1.0
    """kg, each drive wheel."""
    wheel_width: Positive = 0.04
    """m, each drive wheel."""
    caster_mass: Positive = 0.5
    """kg, each of the two frictionless casters (front and rear)."""
    max_wheel_torque: Positive = 20.0
    """Motor torque limit in N·m; commanded torques are saturated to ±this."""
    wheel_friction: Positive = 1.0
    """Lateral friction coefficient of the drive wheels."""
    bump_release: Positive = 0.05
    """Simulated seconds without contact before touching the same obstacle again is a new bump."""


class LocalizationConfig(_Section, frozen=True):
    initial_x: float = 0.0
    """Initial pose published before the first fix: x in m."""
    initial_y: float = 0.0
    """Initial pose: y in m."""
    initial_theta: float = 0.0
    """Initial pose: heading in rad."""
    rate: Positive = 1.0
    """Fixes per second of simulation time."""
    noise_x: NonNegative = 0.0
    """Standard deviation of the Gaussian noise added to a fix's x, in m (0 = exact)."""
    noise_y: NonNegative = 0.0
    """Standard deviation of the noise on y, in m."""
    noise_theta: NonNegative = 0.0
    """Standard deviation of the noise on theta, in rad."""
    seed: Annotated[int, msgspec.Meta(ge=0)] | None = None
    """Random seed for the noise (>= 0); None (``"none"``) draws one from the OS (shown in status)."""


class DriveConfig(_Section, frozen=True):
    rate: Positive = 50.0
    """Target velocities per second of simulation time."""
    cruise_speed: Positive = 0.3
    """Path follower forward speed in m/s."""
    max_turn_rate: Positive = 1.0
    """Path follower turn rate limit in rad/s."""
    lookahead: Positive = 0.25
    """Pure pursuit lookahead distance in m."""
    goal_tolerance: Positive = 0.02
    """Distance in m at which a waypoint counts as reached (passing it along the path counts too)."""
    turn_in_place_angle: Positive = math.radians(45.0)
    """Heading error above which the follower stops and turns in place (also: a corner sharper
    than this is a stop)."""
    heading_tolerance: Positive = math.radians(2.0)
    """Heading error below which a turn in place ends and the follower drives on."""
    max_acceleration: Positive = 0.5
    """Path follower limit on the rate of change of vx in m/s^2 (a step in wheel speed slips)."""
    max_angular_acceleration: Positive = 2.0
    """Path follower limit on the rate of change of w in rad/s^2."""
    pose_timeout: Positive = 0.5
    """Seconds of simulation time after which an odometry pose is too old to follow a path on:
    the drive then commands zero until a fresh one arrives."""
    give_up_after_stop: Positive | None = 2.0
    """Simulated seconds the motor may stay latched stopped (a bump, an emergency stop) before the
    drive gives its scenario up (``aborted``); None (``"none"``): it waits for a ``clear`` for ever."""
    time_limit_factor: Positive | None = 3.0
    """A pass of a scenario lasting longer than this many times its planned duration, plus
    ``time_limit_margin``, is given up (``timed_out``), unless the scenario sets its own
    ``time_limit``; None (``"none"``): only a scenario's own limit applies."""
    time_limit_margin: NonNegative = 10.0
    """Simulated seconds added to the time limit a scenario gets from ``time_limit_factor``."""


Covariance = tuple[NonNegative, NonNegative, NonNegative, NonNegative, NonNegative, NonNegative]
"""The diagonal of a 6x6 covariance (x, y, z, roll, pitch, yaw), as diff_drive_controller takes it."""
FrameId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_/]*$")]


NAMESPACE = re.compile(r"^(/?[A-Za-z][A-Za-z0-9_]*)*/?$")
"""A ROS namespace: "" (none), or names of letters, digits and underscores, each starting with a
letter, joined by ``/`` (a leading or trailing ``/`` is the same namespace)."""


class TfLayout(StrEnum):
    """Where a namespaced ROS 2 bridge publishes its transforms (``ros2.tf``, docs/ros2.md)."""

    NAMESPACED = "namespaced"
    PREFIXED = "prefixed"


class Ros2Config(_Section, frozen=True):
    """``invent ros2``: the robot as ROS 2 sees it over rmw_zenoh (docs/ros2.md)."""

    namespace: Annotated[str, msgspec.Meta(pattern=NAMESPACE.pattern)] = ""
    """ROS namespace of the bridge's node, topics and services (``--namespace``): "" = none, or
    names of letters, digits and underscores (each starting with a letter) joined by ``/``."""
    node_name: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z][A-Za-z0-9_]*$")] = "invent_bridge"
    tf: TfLayout = TfLayout.NAMESPACED
    """How a bridge in a namespace publishes TF (with no namespace both are ``/tf`` and ``/tf_static``,
    frames as named): ``namespaced`` on ``<ns>/tf`` and ``<ns>/tf_static`` with the frames as named,
    as Nav2's multi-robot bringup has it; ``prefixed`` on the shared ``/tf`` and ``/tf_static`` with
    the robot's frames prefixed ``<ns>/`` (``map`` stays the world's), for one RViz showing every robot."""
    publish_clock: bool = True
    """Whether this bridge publishes ``/clock``: one per ROS domain should (in a fleet, the first robot's)."""
    distro: Literal["jazzy", "kilted", "rolling", "humble"] = "jazzy"
    """The ROS 2 release of the nodes to talk to: Humble's rmw_zenoh has no type hashes and writes
    ``TypeHashNotSupported`` in their place in keys and tokens; the others the RIHS01 hash."""
    map_frame: FrameId = "map"
    odom_frame: FrameId = "odom"
    base_frame: FrameId = "base_link"
    """The robot's root frame (the axle centre, as the sim's body pose); the URDF's root link."""
    publish_rate: Positive = 50.0
    """``/odom``, ``/tf`` and ``/joint_states`` per second of simulation time (diff_drive_controller's
    ``publish_rate``)."""
    clock_rate: Positive = 100.0
    """``/clock`` messages per second of simulation time: the resolution of ROS time with ``use_sim_time``."""
    cmd_vel_rate: Positive = 50.0
    """The most ``/cmd_vel`` messages forwarded as target velocities per second of simulation time;
    between two, only the newest is kept (a flood is coalesced and counted)."""
    pose_covariance: Covariance = (0.001, 0.001, 0.001, 0.001, 0.001, 0.01)
    """``/odom`` pose covariance diagonal (diff_drive_controller's default)."""
    twist_covariance: Covariance = (0.001, 0.001, 0.001, 0.001, 0.001, 0.01)
    """``/odom`` twist covariance diagonal (diff_drive_controller's default)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("pose_covariance", "twist_covariance"):
            if not all(math.isfinite(value) for value in getattr(self, name)):
                raise ValueError(f"`{name}` must be finite")


class InputConfig(_Section, frozen=True):
    """What every service accepts as plausible input (docs/input.md). Outside these bounds a
    well-formed sample is bad input: dropped, counted, and its stamp never moves a time base."""

    stamp_horizon: Positive = 1.0
    """Simulated seconds a stamp may run ahead of the time base it is checked against (the
    previous sample of the same stream, or the wheel-angle time for targets and fixes)."""
    max_wheel_speed: Positive = 50.0
    """rad/s: a wheel-angle step, or a target velocity, implying a faster wheel is implausible
    (the default robot's top speed, 1 m/s at the motor's default limits, is 10 rad/s)."""
    max_gain: Positive = 1000.0
    """Ceiling on each PD gain, from the configuration or set_pd_gain."""
    max_coordinate: Positive = 10_000.0
    """m: a pose (localization fix, odometry pose, simulated pose) further than this from the
    origin on either axis is implausible."""

    @property
    def stamp_horizon_ns(self) -> int:
        """``stamp_horizon`` in the integer nanoseconds stamps are compared in."""
        return round(self.stamp_horizon * NANOSECONDS_PER_SECOND)


class RecordRate(StrEnum):
    OBSERVED = "observed"
    EVERY_STEP = "every_step"


class RecordConfig(_Section, frozen=True):
    """What ``invent up`` records (its ``run.mcap``, and the journals the services keep meanwhile:
    README.md, "Rates and bounds")."""

    rate: RecordRate = RecordRate.OBSERVED
    """``observed``: every key at the observed steps (``sim.observe_every``), as the loop publishes
    them, what the report, plots and views need; ``every_step``: the control path and the poses at
    every simulation step too, for debugging the loop (about ten times the size)."""
    max_size: Positive | None = 1024.0
    """MB: the recording stops here (the run goes on), the journals of the run sharing it."""
    max_duration: Positive | None = None
    """Simulated seconds: nothing stamped later is recorded."""
    split_size: Positive | None = None
    """MB: a new file of the recording (``run_1.mcap``, ...) once a file has this much."""
    split_duration: Positive | None = None
    """Simulated seconds each file of the recording covers."""
    min_free_disk: NonNegative = 256.0
    """MB: the recording stops when less than this is free on its disk (the run goes on)."""

    @property
    def every_step(self) -> bool:
        return self.rate is RecordRate.EVERY_STEP


class GcPolicy(StrEnum):
    AUTOMATIC = "automatic"
    FROZEN = "frozen"
    IDLE = "idle"


CpuId = Annotated[int, msgspec.Meta(ge=0)]


class CpuChoice(StrEnum):
    LAST = "last"
    """The last CPU the process may use: every process of the control path on that same one."""
    ANY = "any"
    """Wherever the system likes."""


class RtConfig(_Section, frozen=True):
    """Real-time settings of the control path's processes (``--rt``: the sim, the motor, the router;
    docs/realtime.md). Opt-in; what the system refuses is said in one line and skipped."""

    enabled: bool = False
    """SCHED_FIFO, locked memory, the CPUs and the collector below (``--rt`` sets it)."""
    priority: Annotated[int, msgspec.Meta(ge=1, le=99)] = 50
    """SCHED_FIFO priority, 1..99 (ros2_control's controller manager runs at 50)."""
    lock_memory: bool = True
    """``mlockall``: every page of the process kept in memory, now and later."""
    cpus: tuple[CpuId, ...] | CpuChoice = CpuChoice.LAST
    """CPUs the process runs on (its threads too): a list, ``"last"`` (the last CPU it may use, so
    that the control path's processes share one core and hand each step over without waking
    another: measured the best here, docs/realtime.md) or ``"any"`` (wherever the system likes)."""
    gc: GcPolicy = GcPolicy.FROZEN
    """Python's garbage collector: ``automatic`` (as ever), ``frozen`` (what start-up made is frozen
    and never scanned again), ``idle`` (frozen, and the young generation collected when the service
    thread is about to wait; automatic collections only as a safety net)."""


class Config(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    robot: RobotConfig = msgspec.field(default_factory=RobotConfig)
    motor: MotorConfig = msgspec.field(default_factory=MotorConfig)
    odometry: OdometryConfig = msgspec.field(default_factory=OdometryConfig)
    sim: SimConfig = msgspec.field(default_factory=SimConfig)
    localization: LocalizationConfig = msgspec.field(default_factory=LocalizationConfig)
    drive: DriveConfig = msgspec.field(default_factory=DriveConfig)
    input: InputConfig = msgspec.field(default_factory=InputConfig)
    ros2: Ros2Config = msgspec.field(default_factory=Ros2Config)
    record: RecordConfig = msgspec.field(default_factory=RecordConfig)
    rt: RtConfig = msgspec.field(default_factory=RtConfig)

    def __post_init__(self) -> None:
        motor, ceiling = self.motor, self.input.max_gain
        for name in ("p_gain_l", "p_gain_r", "d_gain_l", "d_gain_r"):
            if getattr(motor, name) > ceiling:
                raise ValueError(f"`motor.{name}` = {getattr(motor, name)} is above `input.max_gain` = {ceiling}")

    @property
    def geometry(self) -> CalibratedGeometry:
        """The robot's wheel radii and half axle with the calibration applied."""
        return CalibratedGeometry.of(self.robot, self.odometry)


SECTIONS: dict[str, type[msgspec.Struct]] = {
    name: msgspec.inspect.type_info(Config).fields[index].type.cls  # type: ignore[attr-defined]
    for index, name in enumerate(Config.__struct_fields__)
}
"""Each table of the robot description, by name, and its section struct."""


SEED_NAMES: dict[str, str] = {
    "PGainL": "motor.p_gain_l",
    "PGainR": "motor.p_gain_r",
    "DGainL": "motor.d_gain_l",
    "DGainR": "motor.d_gain_r",
    "SimulatedOffsetX": "motor.simulated_offset_x",
    "SimulatedOffsetY": "motor.simulated_offset_y",
    "SimulatedOffsetAngle": "motor.simulated_offset_angle",
    "leftWheelID": "robot.left_wheel_id",
    "rightWheelID": "robot.right_wheel_id",
    "radiusOfLeftWheel": "robot.radius_of_left_wheel",
    "radiusOfRightWheel": "robot.radius_of_right_wheel",
    "lengthOfAxle": "robot.length_of_axle",
    "radiusOfBodyArea": "robot.radius_of_body_area",
    "RotationAngleBorder": "odometry.rotation_angle_border",
    "RhoBorder": "odometry.rho_border",
}
"""Seed configuration name -> config key (the table in docs/configuration.md)."""


def _build(raw: dict[str, Any]) -> Config:
    _read_nones(raw)
    try:
        return msgspec.convert(raw, Config)
    except msgspec.ValidationError as error:
        message = str(error).replace("$.", "")
        field = message.rpartition(" - at `")[2].rstrip("`").split(".")
        if len(field) == 2 and field[1] in optional_fields(SECTIONS.get(field[0], _Section)):
            message += f' (write "{NONE}" to turn it off)'
        raise ConfigError(message) from None


def _read_nones(raw: dict[str, Any]) -> None:
    """Every optional parameter written :data:`NONE` becomes None (in place)."""
    for section, section_type in SECTIONS.items():
        table = raw.get(section)
        if not isinstance(table, dict):
            continue
        for name in optional_fields(section_type):
            value = table.get(name)
            if isinstance(value, str) and value.strip().lower() == NONE:
                table[name] = None


StructT = TypeVar("StructT", bound=msgspec.Struct)


def convert_toml(text: str, struct_type: type[StructT], what: str) -> StructT:
    """A ``struct_type`` from TOML text (a world, scenario or fleet file), strictly: ConfigError
    starting with ``what`` (the file) and naming the offending field otherwise."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{what}: {error}") from None
    try:
        return msgspec.convert(raw, struct_type)
    except msgspec.ValidationError as error:
        raise ConfigError(f"{what}: {str(error).replace('$.', '')}") from None


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"motor.p_gain_l=3"`` -> (["motor", "p_gain_l"], 3). The value is read as TOML, else as a string."""
    path, sep, value_text = text.partition("=")
    if not sep or not path.strip():
        raise ConfigError(f"override {text!r} must be SECTION.KEY=VALUE")
    try:
        value = tomllib.loads(f"v = {value_text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = value_text.strip()
    return path.strip().split("."), value


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load the robot description, then apply ``overrides`` ({"motor.p_gain_l": 3.0, ...}).

    Override values of None are skipped, so unset command-line flags keep the file's value.
    """
    return config_from_description(read_description(path, overrides))


def config_from_description(raw: dict[str, Any]) -> Config:
    """The typed robot description of the tables ``raw`` (as :func:`read_description` gives them);
    ConfigError naming the field. ``raw`` is not changed."""
    return _build(copy.deepcopy(raw))


def read_description(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The robot description's tables as written: the file (none: empty), then ``overrides``
    (None values skipped), unchecked and without defaults: what :func:`description_toml` writes back."""
    raw: dict[str, Any] = {}
    if path is not None:
        try:
            raw = tomllib.loads(Path(path).read_text())
        except OSError as error:
            raise ConfigError(f"config file {path}: {error.strerror}") from None
        except tomllib.TOMLDecodeError as error:
            raise ConfigError(f"config file {path}: {error}") from None
    for dotted, value in (overrides or {}).items():
        if value is None:
            continue
        *sections, field = dotted.split(".")
        table = raw
        for section in sections:
            table = table.setdefault(section, {})
            if not isinstance(table, dict):
                raise ConfigError(f"`{dotted}`: `{section}` is not a table")
        table[field] = value
    return raw


def description_toml(raw: dict[str, Any]) -> str:
    """TOML text of a robot description's tables (:func:`read_description`): its top-level values,
    then one ``[section]`` per table, keys in their order; a None is written :data:`NONE`."""
    scalars = {name: value for name, value in raw.items() if not isinstance(value, dict)}
    lines = [f"{name} = {_toml_value(value)}" for name, value in scalars.items()]
    for name, table in raw.items():
        if isinstance(table, dict):
            lines += ["", f"[{name}]", *(f"{key} = {_toml_value(value)}" for key, value in table.items())]
    return "\n".join(lines).lstrip("\n") + "\n"


def _toml_value(value: Any) -> str:
    if value is None:
        return json.dumps(NONE)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)  # a float's repr reads back as the same float (TOML takes 1e-05 and 0.1)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    raise ConfigError(f"cannot write {value!r} ({type(value).__name__}) in a robot description")
