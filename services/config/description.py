"""The whole robot description: one TOML file, a shared ``[robot]`` table and one table per service."""

from __future__ import annotations

import msgspec

from services.config import amcl, navigation, run_sections, sections, sensors


class Config(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """The robot description, typed: one section per table, each table optional (its defaults)."""

    robot: sections.RobotConfig = msgspec.field(default_factory=sections.RobotConfig)
    motor: sections.MotorConfig = msgspec.field(default_factory=sections.MotorConfig)
    odometry: sections.OdometryConfig = msgspec.field(default_factory=sections.OdometryConfig)
    sim: sections.SimConfig = msgspec.field(default_factory=sections.SimConfig)
    localization: sections.LocalizationConfig = msgspec.field(default_factory=sections.LocalizationConfig)
    amcl: amcl.AmclConfig = msgspec.field(default_factory=amcl.AmclConfig)
    drive: sections.DriveConfig = msgspec.field(default_factory=sections.DriveConfig)
    goals: sections.GoalsConfig = msgspec.field(default_factory=sections.GoalsConfig)
    input: sections.InputConfig = msgspec.field(default_factory=sections.InputConfig)
    lidar: sensors.LidarConfig = msgspec.field(default_factory=sensors.LidarConfig)
    imu: sensors.ImuConfig = msgspec.field(default_factory=sensors.ImuConfig)
    collision_monitor: sensors.CollisionMonitorConfig = msgspec.field(default_factory=sensors.CollisionMonitorConfig)
    navigation: navigation.NavigationConfig = msgspec.field(default_factory=navigation.NavigationConfig)
    ros2: run_sections.Ros2Config = msgspec.field(default_factory=run_sections.Ros2Config)
    record: run_sections.RecordConfig = msgspec.field(default_factory=run_sections.RecordConfig)
    rt: run_sections.RtConfig = msgspec.field(default_factory=run_sections.RtConfig)

    def __post_init__(self) -> None:
        motor, ceiling = self.motor, self.input.max_gain
        for name in ("p_gain_l", "p_gain_r", "d_gain_l", "d_gain_r"):
            if getattr(motor, name) > ceiling:
                raise ValueError(f"`motor.{name}` = {getattr(motor, name)} is above `input.max_gain` = {ceiling}")
        if self.localization.mode == "amcl" and self.navigation.map is None:
            raise ValueError('`localization.mode` = "amcl" localizes on a map: give `navigation.map` (--map FILE)')

    @property
    def geometry(self) -> sections.CalibratedGeometry:
        """The robot's wheel radii and half axle with the calibration applied."""
        return sections.CalibratedGeometry.of(self.robot, self.odometry)


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
