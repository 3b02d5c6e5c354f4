"""The robot description: one TOML file, a shared ``[robot]`` table and one table per service.

Defaults are the seeds' (SPEC section 3); every default lives here and nowhere else.
Loading is typed and strict (msgspec): an unknown key, a wrong type or a value out of range
raises :class:`ConfigError` naming the field, and the CLI exits with code 2.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from schemas.keys import DEFAULT_ROBOT, validate_robot_name

Positive = Annotated[float, msgspec.Meta(gt=0.0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0)]
WheelId = Annotated[int, msgspec.Meta(ge=0)]


class ConfigError(ValueError):
    """An invalid configuration file, value or override; the message names the field."""


class _Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    def __post_init__(self) -> None:
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"`{name}` must be finite, got {value}")


class RobotConfig(_Section):
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


class MotorConfig(_Section):
    p_gain_l: NonNegative = 5.0
    p_gain_r: NonNegative = 5.0
    d_gain_l: NonNegative = 2.0
    d_gain_r: NonNegative = 2.0
    simulated_offset_x: float = 0.0
    simulated_offset_y: float = 0.0
    simulated_offset_angle: float = 0.0
    command_timeout: NonNegative = 0.5
    """Seconds of wheel-angle time without a target velocity before braking to zero; 0 disables."""
    target_angle: Literal["seed", "integrated"] = "seed"
    max_vx: Positive | None = None
    """Limit on |vx| in m/s; None (default) = no limit, the seed's behaviour."""
    max_ax: Positive | None = None
    """Limit on the rate of change of vx in m/s^2."""
    max_w: Positive | None = None
    """Limit on |w| in rad/s."""
    max_aw: Positive | None = None
    """Limit on the rate of change of w in rad/s^2."""


class OdometryConfig(_Section):
    rotation_angle_border: Positive = math.pi / 180.0
    rho_border: Positive = 10000.0
    left_radius_scale: Positive = 1.0
    """Calibration multiplier on the left wheel radius (SPEC 9.6: 1.0 = no calibration)."""
    right_radius_scale: Positive = 1.0
    axle_scale: Positive = 1.0


class SimConfig(_Section):
    mode: Literal["lockstep", "realtime"] = "lockstep"
    step: Positive = 0.001
    """Simulated seconds per physics step."""
    lockstep_timeout: Positive = 0.5
    """Wall seconds a lockstep step waits for its torque before applying zero and going on."""
    realtime_factor: Positive = 1.0
    """Realtime mode: simulated seconds per wall second."""
    world: str | None = None
    """World file (TOML); None = an empty floor."""
    body_mass: Positive = 20.0
    body_height: Positive = 0.15
    wheel_mass: Positive = 1.0
    wheel_width: Positive = 0.04
    caster_mass: Positive = 0.5
    max_wheel_torque: Positive = 20.0
    """Motor torque limit in N·m; commanded torques are saturated to ±this."""
    wheel_friction: Positive = 1.0


class LocalizationConfig(_Section):
    initial_x: float = 0.0
    initial_y: float = 0.0
    initial_theta: float = 0.0
    rate: Positive = 1.0
    """Fixes per second of simulation time."""
    noise_x: NonNegative = 0.0
    noise_y: NonNegative = 0.0
    noise_theta: NonNegative = 0.0
    seed: int | None = None
    """Random seed for the noise; None draws one from the OS."""


class DriveConfig(_Section):
    rate: Positive = 50.0
    """Target velocities per second of simulation time."""
    cruise_speed: Positive = 0.3
    """Path follower forward speed in m/s."""
    max_turn_rate: Positive = 1.0
    """Path follower turn rate limit in rad/s."""
    lookahead: Positive = 0.25
    """Pure pursuit lookahead distance in m."""
    goal_tolerance: Positive = 0.02
    """Distance in m at which the last waypoint counts as reached."""
    turn_in_place_angle: Positive = math.radians(45.0)
    """Heading error above which the follower stops and turns in place."""


class Config(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    robot: RobotConfig = msgspec.field(default_factory=RobotConfig)
    motor: MotorConfig = msgspec.field(default_factory=MotorConfig)
    odometry: OdometryConfig = msgspec.field(default_factory=OdometryConfig)
    sim: SimConfig = msgspec.field(default_factory=SimConfig)
    localization: LocalizationConfig = msgspec.field(default_factory=LocalizationConfig)
    drive: DriveConfig = msgspec.field(default_factory=DriveConfig)


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
    try:
        return msgspec.convert(raw, Config)
    except msgspec.ValidationError as error:
        raise ConfigError(str(error).replace("$.", "")) from None


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
    return _build(raw)
