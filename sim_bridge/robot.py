"""The diff-drive robot as a PyBullet multibody, built from the robot description.

Frames (docs/protocol.md section 6; docs/sim.md has a drawing):

- The base frame sits on the axle centre, x forward, y to the left, z up. The base's centre
  of mass is placed there too, so PyBullet's base pose *is* the axle-centre pose reported on
  ``sim/body_pose``.
- The body is a cylinder of radius ``robot.radius_of_body_area`` and height
  ``sim.body_height`` whose bottom is at axle height.
- The two drive wheels are links on continuous (unlimited revolute) joints at y = ±b, their
  link frames unrotated with the joint axis +y, so positive torque and positive angle mean
  forward for both. A wheel collides as a sphere of the wheel's radius: its floor contact is
  right under the axle. (A cylinder lying on a plane touches it at one rim edge, a different
  edge for each wheel, which loads the wheels unevenly and makes the robot veer.) The inertia
  is a solid disc of ``sim.wheel_width``, and the GUI draws a disc.
- The body's inertia is a solid cylinder of ``sim.body_mass`` (PyBullet's default would be the
  bounding box of the offset shape).
- Two passive casters (front and rear) are frictionless spheres on fixed joints, just clear
  of the floor: with friction they would pin the robot in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pybullet as p

from services.config import RobotConfig, SimConfig
from sim_bridge.geometry import CASTER_RADIUS_FRACTION, CASTER_REACH_FRACTION
from sim_bridge.world import InitialPose

CASTER_CLEARANCE = 0.002
"""m between a caster and the floor when the robot stands level.

Four rigid contacts on a plane leave the load split arbitrary: with the casters touching,
PyBullet puts most of the weight on them and the wheels slip. With this gap the wheels carry
the weight and a caster only touches when the body pitches (hard acceleration or braking).
"""

_WHEEL_ORIENTATION = p.getQuaternionFromEuler((math.pi / 2.0, 0.0, 0.0))
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
_ORIGIN = (0.0, 0.0, 0.0)
_WHEEL_AXIS = (0.0, 1.0, 0.0)
_BASE = -1
_BODY_COLOUR = (0.85, 0.85, 0.9, 1.0)
_WHEEL_COLOUR = (0.15, 0.15, 0.15, 1.0)


def _cylinder_inertia(mass: float, radius: float, height: float) -> tuple[float, float, float]:
    """Principal moments of a solid cylinder whose axis is z."""
    across = mass * (3.0 * radius**2 + height**2) / 12.0
    return across, across, mass * radius**2 / 2.0


def _wheel_inertia(mass: float, radius: float, width: float) -> tuple[float, float, float]:
    """Principal moments of a solid disc wheel whose axis is y."""
    across, _, spin = _cylinder_inertia(mass, radius, width)
    return across, spin, across


@dataclass(frozen=True)
class RobotModel:
    """A robot built in one physics client."""

    body: int
    wheel_joints: tuple[int, int]
    """Joint (= link) indices of the left and right wheel."""
    caster_links: tuple[int, int]
    axle_height: float
    """Height of the axle centre above the floor when the robot stands on it."""


def build_robot(client: int, robot: RobotConfig, sim: SimConfig, pose: InitialPose) -> RobotModel:
    """Create the robot in ``client`` standing on the floor at ``pose``; its wheel motors are disabled."""
    left_radius, right_radius = robot.radius_of_left_wheel, robot.radius_of_right_wheel
    axle_height = (left_radius + right_radius) / 2.0
    caster_radius = CASTER_RADIUS_FRACTION * min(left_radius, right_radius)
    caster_x = CASTER_REACH_FRACTION * robot.radius_of_body_area
    caster_z = CASTER_CLEARANCE + caster_radius - axle_height

    body_shape = p.createCollisionShape(
        p.GEOM_CYLINDER,
        radius=robot.radius_of_body_area,
        height=sim.body_height,
        collisionFramePosition=(0.0, 0.0, sim.body_height / 2.0),
        physicsClientId=client,
    )
    body_visual = p.createVisualShape(
        p.GEOM_CYLINDER,
        radius=robot.radius_of_body_area,
        length=sim.body_height,
        visualFramePosition=(0.0, 0.0, sim.body_height / 2.0),
        rgbaColor=_BODY_COLOUR,
        physicsClientId=client,
    )

    def wheel_shapes(radius: float) -> tuple[int, int]:
        collision = p.createCollisionShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client)
        visual = p.createVisualShape(
            p.GEOM_CYLINDER,
            radius=radius,
            length=sim.wheel_width,
            visualFrameOrientation=_WHEEL_ORIENTATION,
            rgbaColor=_WHEEL_COLOUR,
            physicsClientId=client,
        )
        return collision, visual

    left_shapes, right_shapes = wheel_shapes(left_radius), wheel_shapes(right_radius)
    caster_shape = p.createCollisionShape(p.GEOM_SPHERE, radius=caster_radius, physicsClientId=client)
    link_masses = (sim.wheel_mass, sim.wheel_mass, sim.caster_mass, sim.caster_mass)
    link_shapes = (left_shapes[0], right_shapes[0], caster_shape, caster_shape)
    link_visuals = (left_shapes[1], right_shapes[1], -1, -1)
    link_positions = (
        (0.0, robot.half_axle, 0.0),
        (0.0, -robot.half_axle, 0.0),
        (caster_x, 0.0, caster_z),
        (-caster_x, 0.0, caster_z),
    )
    link_count = len(link_masses)
    body = p.createMultiBody(
        baseMass=sim.body_mass,
        baseCollisionShapeIndex=body_shape,
        baseVisualShapeIndex=body_visual,
        basePosition=(pose.x, pose.y, axle_height),
        baseOrientation=p.getQuaternionFromEuler((0.0, 0.0, pose.theta)),
        linkMasses=link_masses,
        linkCollisionShapeIndices=link_shapes,
        linkVisualShapeIndices=link_visuals,
        linkPositions=link_positions,
        linkOrientations=(_IDENTITY,) * link_count,
        linkInertialFramePositions=(_ORIGIN,) * link_count,
        linkInertialFrameOrientations=(_IDENTITY,) * link_count,
        linkParentIndices=(0,) * link_count,
        linkJointTypes=(p.JOINT_REVOLUTE, p.JOINT_REVOLUTE, p.JOINT_FIXED, p.JOINT_FIXED),
        linkJointAxis=(_WHEEL_AXIS,) * link_count,
        physicsClientId=client,
    )
    wheels, casters = (0, 1), (2, 3)
    p.changeDynamics(
        body,
        _BASE,
        linearDamping=0.0,
        angularDamping=0.0,
        localInertiaDiagonal=_cylinder_inertia(sim.body_mass, robot.radius_of_body_area, sim.body_height),
        physicsClientId=client,
    )
    for wheel, radius in zip(wheels, (left_radius, right_radius), strict=True):
        p.changeDynamics(
            body,
            wheel,
            lateralFriction=sim.wheel_friction,
            localInertiaDiagonal=_wheel_inertia(sim.wheel_mass, radius, sim.wheel_width),
            physicsClientId=client,
        )
    for caster in casters:
        p.changeDynamics(
            body, caster, lateralFriction=0.0, rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client
        )
    p.setJointMotorControlArray(body, wheels, p.VELOCITY_CONTROL, forces=(0.0, 0.0), physicsClientId=client)
    return RobotModel(body=body, wheel_joints=wheels, caster_links=casters, axle_height=axle_height)
