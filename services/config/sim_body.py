"""What the simulated robot may differ in from the description every other service reads:
``--sim-set SECTION.KEY=VALUE`` (``invent up``, ``invent control``, ``invent calibrate umbmark``).
The "true" robot: its body (wheel radii, axle, masses, friction) and its sensors' imperfections
(the lidar's and the IMU's noise, the IMU's biases), which only the simulator adds; never the loop's
settings, which the services share."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from services.config.loading import parse_override
from services.errors import ConfigError

SIM_BODY_KEYS = (
    "robot.radius_of_left_wheel",
    "robot.radius_of_right_wheel",
    "robot.length_of_axle",
    "robot.radius_of_body_area",
    "sim.body_mass",
    "sim.body_height",
    "sim.wheel_mass",
    "sim.wheel_width",
    "sim.caster_mass",
    "sim.wheel_friction",
    "sim.max_wheel_torque",
    "lidar.noise",
    "lidar.seed",
    "imu.gyro_noise",
    "imu.accel_noise",
    "imu.gyro_bias",
    "imu.accel_bias",
    "imu.seed",
)
"""What ``--sim-set`` may change: the simulated body and its sensors' noise, not the loop."""
SIM_SET_FLAG = "--sim-set"


def parse_sim_set(texts: Iterable[str], flag: str = SIM_SET_FLAG) -> dict[str, Any]:
    """``--sim-set`` texts (``KEY=VALUE``, the value read as ``--set`` reads it) as overrides, in
    order; ConfigError naming the one that is not ``KEY=VALUE`` or whose key is not of
    :data:`SIM_BODY_KEYS`."""
    overrides: dict[str, Any] = {}
    for text in texts:
        try:
            key, value = parse_override(text)
        except ConfigError:
            raise ConfigError(f"{flag} {text!r} must be KEY=VALUE") from None
        if key not in SIM_BODY_KEYS:
            raise ConfigError(
                f"{flag} {key}: only the simulated body and its sensors' noise may differ from the description: "
                + ", ".join(SIM_BODY_KEYS)
            )
        overrides[key] = value
    return overrides
