"""The sensor sections of the robot description: the 2D lidar and the IMU (what the simulator
casts and measures, and where each sits on the body: the URDF's ``base_scan`` and ``imu_link``),
and the motor's collision monitor that holds the robot from the scan before it touches.

Mount poses are on the base frame (the axle centre, x forward, y left, z up: services/body/geometry.py).
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

from schemas.messages import MAX_SCAN_RAYS
from services.config.fields import (
    METRES,
    METRES_PER_SECOND_SQUARED,
    PER_SIMULATED_SECOND,
    RADIANS,
    RADIANS_PER_SECOND,
    SIMULATED_SECONDS,
    NonNegative,
    Positive,
    Section,
)

FULL_CIRCLE = 2.0 * math.pi
Seed = Annotated[int, msgspec.Meta(ge=0)]


class LidarConfig(Section, frozen=True):
    """The robot's 2D lidar: a ring of rays the simulator casts in the world at ``rate``, published
    on ``sim/scan``. Ray i points at ``-span/2 + i * span/rays`` about the lidar's z, so a full
    circle has no ray twice."""

    enabled: bool = True
    """Whether the simulator casts the scan (false: no ``sim/scan``, a robot without a lidar)."""
    x: Annotated[float, METRES] = 0.0
    """Where the lidar sits on the base frame, along x."""
    y: Annotated[float, METRES] = 0.0
    """Along y."""
    z: Annotated[float, METRES] = 0.1
    """Height of the scan plane above the axle centre: within the body's height by default, as a
    safety scanner sits in a slot of an AMR's body, so that it sees other robots' bodies. The
    simulator starts each ray where it leaves the robot's own body, which it never sees."""
    yaw: Annotated[float, RADIANS] = 0.0
    """The lidar's heading on the base (its x: the scan's angle 0)."""
    rays: Annotated[int, msgspec.Meta(ge=1, le=MAX_SCAN_RAYS)] = 360
    """Rays per scan."""
    span: Annotated[float, msgspec.Meta(gt=0.0, le=FULL_CIRCLE), RADIANS] = FULL_CIRCLE
    """The angle the rays cover, centred on the lidar's x (2π: all round)."""
    range_min: Annotated[NonNegative, METRES] = 0.12
    """The shortest range the lidar reports (ROS's ``range_min``)."""
    range_max: Annotated[Positive, METRES] = 3.5
    """The longest: a ray that hits nothing within it reads +inf."""
    rate: Annotated[Positive, PER_SIMULATED_SECOND] = 10.0
    """Scans per second of simulation time."""
    noise: Annotated[NonNegative, METRES] = 0.0
    """Standard deviation of the Gaussian noise added to each range (0 = exact)."""
    seed: Seed = 0
    """Random seed of the noise (the same seed gives the same scans; each robot of a fleet draws
    its own stream from it)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.range_min >= self.range_max:
            raise ValueError(f"`range_min` = {self.range_min} must be below `range_max` = {self.range_max}")

    @property
    def angle_increment(self) -> float:
        return self.span / self.rays

    @property
    def angle_min(self) -> float:
        return -self.span / 2.0


class ImuConfig(Section, frozen=True):
    """The robot's IMU: the body's angular velocity and specific force at the mount, and the
    orientation the simulator knows (flagged so), published on ``sim/imu`` at ``rate``."""

    enabled: bool = True
    """Whether the simulator measures it (false: no ``sim/imu``)."""
    x: Annotated[float, METRES] = 0.0
    """Where the IMU sits on the base frame, along x; its axes are the base's."""
    y: Annotated[float, METRES] = 0.0
    """Along y."""
    z: Annotated[float, METRES] = 0.05
    """Along z, above the axle centre."""
    rate: Annotated[Positive, PER_SIMULATED_SECOND] = 100.0
    """Samples per second of simulation time."""
    gyro_noise: Annotated[NonNegative, RADIANS_PER_SECOND] = 0.0
    """Standard deviation of the Gaussian noise on each angular velocity (0 = exact)."""
    accel_noise: Annotated[NonNegative, METRES_PER_SECOND_SQUARED] = 0.0
    """Standard deviation of the Gaussian noise on each linear acceleration."""
    gyro_bias: Annotated[tuple[float, float, float], RADIANS_PER_SECOND] = (0.0, 0.0, 0.0)
    """A constant offset on the angular velocity about x, y, z."""
    accel_bias: Annotated[tuple[float, float, float], METRES_PER_SECOND_SQUARED] = (0.0, 0.0, 0.0)
    """A constant offset on the linear acceleration along x, y, z."""
    seed: Seed = 0
    """Random seed of the noise (each robot of a fleet draws its own stream from it)."""


class CollisionMonitorConfig(Section, frozen=True):
    """The motor's collision monitor (as Nav2's): from ``sim/scan``, an obstacle in the stop zone
    along the commanded motion holds the robot (not latched: it drives on when the zone is clear),
    one in the slow-down zone slows it. A motor that never had a scan is not monitored.

    The defaults stop the default robot (motor ``max_vx`` 1 m/s, ``max_ax`` 2 m/s²) short of an
    obstacle at its top speed with a 10 Hz lidar: an obstacle is seen at most one scan period
    (0.1 s: 0.10 m) after it enters the stop zone, and the hold brakes through the acceleration
    limit in v²/2a = 0.25 m, plus the wheels' lag behind the braking command (measured: 0.29 m
    from 1 m/s in all); ``stop_distance`` 0.40 m + ``margin`` 0.05 m (added ahead of the body too)
    leave 0.45 − 0.10 − 0.29 = 0.06 m at worst."""

    enabled: bool = True
    """false: no zones, no scan timeout; the bump alone stops the robot, as before the lidar."""
    stop_distance: Annotated[Positive, METRES] = 0.4
    """Length of the stop zone: how far ahead of the footprint, along the commanded motion, an
    obstacle holds the robot."""
    slow_distance: Annotated[NonNegative, METRES] = 0.8
    """Length of the slow-down zone (0 = none); at least ``stop_distance`` when set."""
    slow_factor: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.5
    """What the commanded speeds are multiplied by while an obstacle is in the slow-down zone."""
    margin: Annotated[NonNegative, METRES] = 0.05
    """Added to the body's radius: the footprint the zones sweep along the motion."""
    scan_timeout: Annotated[Positive, SIMULATED_SECONDS] = 0.5
    """Once scans have come, a scan older than this (against the wheel-angle time) holds the
    robot: no data, no motion."""
    min_points: Annotated[int, msgspec.Meta(ge=1)] = 4
    """How many of a scan's points must lie in a zone for it to act (Nav2's ``min_points``, whose
    default is 4 too): fewer in the stop zone do not hold the robot, fewer in the slow-down zone do
    not slow it, so that a stray return (range noise on something just outside the zone) does not
    stop it; 1 acts on any point. Why 4: the stop zone reaches at most ``stop_distance`` + the
    footprint's radius = 0.9 m from the default lidar (straight ahead), where its 360 rays are 1°,
    16 mm, apart, so the thinnest obstacle a robot must see, a post 0.1 m across, takes 6 or 7 rays
    there; 4 of them lie in the zone 1.2 cm of travel after the first does (2.4 cm for a post that
    would just graze the body's side): the hold comes at most that much later than on one point,
    within the 6 cm the defaults leave above. 5 or 6 would take up to 3.5 or 6 cm, all of it; a
    thinner obstacle, sparser rays or a zone reaching further from the lidar need a smaller value."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if 0.0 < self.slow_distance < self.stop_distance:
            raise ValueError(
                f"`slow_distance` = {self.slow_distance} must be 0 or at least `stop_distance` = {self.stop_distance}"
            )
