"""The robot's body as the simulator builds it, from the robot description: one source for the
PyBullet multibody (:mod:`sim_bridge.robot`), the Foxglove scene (:mod:`services.recording.scene`)
and the URDF the ROS 2 bridge publishes (:mod:`services.ros2.urdf`). Pure: no PyBullet here.

Frames: the base frame sits on the axle centre, x forward, y to the left, z up, at axle height
above the floor. The body is a cylinder whose bottom is at axle height; the two drive wheels turn
about +y at y = ±b (positive angle: forward for both); two frictionless casters (front and rear)
hang on fixed joints just clear of the floor.
"""

from __future__ import annotations

from dataclasses import dataclass

from services.config import RobotConfig, SimConfig

CASTER_RADIUS_FRACTION = 0.5
"""Caster sphere radius as a fraction of the smaller wheel radius."""
CASTER_REACH_FRACTION = 0.7
"""Distance of each caster from the axle centre along x, as a fraction of the body radius."""
CASTER_CLEARANCE = 0.002
"""m between a caster and the floor when the robot stands level.

Four rigid contacts on a plane leave the load split arbitrary: with the casters touching,
PyBullet puts most of the weight on them and the wheels slip. With this gap the wheels carry
the weight and a caster only touches when the body pitches (hard acceleration or braking).
"""


def cylinder_inertia(mass: float, radius: float, height: float) -> tuple[float, float, float]:
    """Principal moments of a solid cylinder whose axis is z."""
    across = mass * (3.0 * radius**2 + height**2) / 12.0
    return across, across, mass * radius**2 / 2.0


def wheel_inertia(mass: float, radius: float, width: float) -> tuple[float, float, float]:
    """Principal moments of a solid disc wheel whose axis is y."""
    across, _, spin = cylinder_inertia(mass, radius, width)
    return across, spin, across


@dataclass(frozen=True)
class Wheel:
    link: str
    """The wheel's link (and frame) name; its joint is ``<link>_joint``."""
    y: float
    """m, from the axle centre along the base's y (left positive)."""
    radius: float
    width: float
    mass: float

    @property
    def joint(self) -> str:
        return f"{self.link}_joint"

    @property
    def inertia(self) -> tuple[float, float, float]:
        return wheel_inertia(self.mass, self.radius, self.width)


@dataclass(frozen=True)
class Caster:
    link: str
    x: float
    """m, from the axle centre along the base's x (front positive)."""
    z: float
    """m, from the axle centre along z (below: negative)."""
    radius: float
    mass: float


@dataclass(frozen=True)
class RobotBody:
    """What the simulator builds for one robot description."""

    axle_height: float
    """m, the axle centre above the floor when the robot stands on it."""
    body_radius: float
    body_height: float
    body_mass: float
    wheels: tuple[Wheel, Wheel]
    """Left, then right."""
    casters: tuple[Caster, Caster]
    """Front, then rear."""

    @property
    def body_inertia(self) -> tuple[float, float, float]:
        return cylinder_inertia(self.body_mass, self.body_radius, self.body_height)

    @property
    def reach(self) -> float:
        """m, the radius about the axle centre that holds every part of the robot seen from above
        (its footprint: the body, or a wheel or caster sticking out of it)."""
        wheels = (abs(wheel.y) + wheel.radius for wheel in self.wheels)
        casters = (abs(caster.x) + caster.radius for caster in self.casters)
        return max(self.body_radius, *wheels, *casters)


def robot_body(robot: RobotConfig, sim: SimConfig) -> RobotBody:
    left_radius, right_radius = robot.radius_of_left_wheel, robot.radius_of_right_wheel
    axle_height = (left_radius + right_radius) / 2.0
    caster_radius = CASTER_RADIUS_FRACTION * min(left_radius, right_radius)
    caster_x = CASTER_REACH_FRACTION * robot.radius_of_body_area
    caster_z = CASTER_CLEARANCE + caster_radius - axle_height
    return RobotBody(
        axle_height=axle_height,
        body_radius=robot.radius_of_body_area,
        body_height=sim.body_height,
        body_mass=sim.body_mass,
        wheels=(
            Wheel("left_wheel", robot.half_axle, left_radius, sim.wheel_width, sim.wheel_mass),
            Wheel("right_wheel", -robot.half_axle, right_radius, sim.wheel_width, sim.wheel_mass),
        ),
        casters=(
            Caster("front_caster", caster_x, caster_z, caster_radius, sim.caster_mass),
            Caster("rear_caster", -caster_x, caster_z, caster_radius, sim.caster_mass),
        ),
    )
