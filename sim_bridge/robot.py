"""The diff-drive robot as a PyBullet multibody, built from :func:`services.body.geometry.robot_body`
(the frames, proportions and masses are there, shared with the Foxglove scene and the URDF).

- The base's centre of mass is on the axle centre, so PyBullet's base pose *is* the axle-centre
  pose reported on ``sim/body_pose``.
- A wheel collides as a sphere of the wheel's radius: its floor contact is right under the axle.
  (A cylinder lying on a plane touches it at one rim edge, a different edge for each wheel, which
  loads the wheels unevenly and makes the robot veer.) Its inertia is a solid disc of
  ``sim.wheel_width``, and the GUI draws a disc.
- The body's inertia is a solid cylinder of ``sim.body_mass`` (PyBullet's default would be the
  bounding box of the offset shape).
- The casters are frictionless spheres: with friction they would pin the robot in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pybullet as p

from services.body.geometry import robot_body
from services.config import RobotConfig, SimConfig
from sim_bridge.world import InitialPose

_WHEEL_ORIENTATION = p.getQuaternionFromEuler((math.pi / 2.0, 0.0, 0.0))
_IDENTITY = (0.0, 0.0, 0.0, 1.0)
_ORIGIN = (0.0, 0.0, 0.0)
_WHEEL_AXIS = (0.0, 1.0, 0.0)
_BASE = -1
_BODY_COLOUR = (0.85, 0.85, 0.9, 1.0)
_WHEEL_COLOUR = (0.15, 0.15, 0.15, 1.0)


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
    shape = robot_body(robot, sim)

    # the body is one cylinder standing on its base: PyBullet takes its collision and its visual
    # shape apart, and names the length and the frame differently in each
    body_frame = (0.0, 0.0, shape.body_height / 2.0)
    body_cylinder = {"radius": shape.body_radius, "physicsClientId": client}
    body_shape = p.createCollisionShape(
        p.GEOM_CYLINDER, height=shape.body_height, collisionFramePosition=body_frame, **body_cylinder
    )
    body_visual = p.createVisualShape(
        p.GEOM_CYLINDER,
        length=shape.body_height,
        visualFramePosition=body_frame,
        rgbaColor=_BODY_COLOUR,
        **body_cylinder,
    )

    def wheel_shapes(radius: float, width: float) -> tuple[int, int]:
        collision = p.createCollisionShape(p.GEOM_SPHERE, radius=radius, physicsClientId=client)
        visual = p.createVisualShape(
            p.GEOM_CYLINDER,
            radius=radius,
            length=width,
            visualFrameOrientation=_WHEEL_ORIENTATION,
            rgbaColor=_WHEEL_COLOUR,
            physicsClientId=client,
        )
        return collision, visual

    wheel_shape_pairs = [wheel_shapes(wheel.radius, wheel.width) for wheel in shape.wheels]
    caster_shapes = [
        p.createCollisionShape(p.GEOM_SPHERE, radius=caster.radius, physicsClientId=client) for caster in shape.casters
    ]
    link_masses = (*(wheel.mass for wheel in shape.wheels), *(caster.mass for caster in shape.casters))
    link_shapes = (*(pair[0] for pair in wheel_shape_pairs), *caster_shapes)
    link_visuals = (*(pair[1] for pair in wheel_shape_pairs), -1, -1)
    link_positions = (
        *((0.0, wheel.y, 0.0) for wheel in shape.wheels),
        *((caster.x, 0.0, caster.z) for caster in shape.casters),
    )
    link_count = len(link_masses)
    body = p.createMultiBody(
        baseMass=shape.body_mass,
        baseCollisionShapeIndex=body_shape,
        baseVisualShapeIndex=body_visual,
        basePosition=(pose.x, pose.y, shape.axle_height),
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
        localInertiaDiagonal=shape.body_inertia,
        physicsClientId=client,
    )
    for joint, wheel in zip(wheels, shape.wheels, strict=True):
        p.changeDynamics(
            body,
            joint,
            lateralFriction=sim.wheel_friction,
            localInertiaDiagonal=wheel.inertia,
            physicsClientId=client,
        )
    for caster in casters:
        p.changeDynamics(
            body, caster, lateralFriction=0.0, rollingFriction=0.0, spinningFriction=0.0, physicsClientId=client
        )
    p.setJointMotorControlArray(body, wheels, p.VELOCITY_CONTROL, forces=(0.0, 0.0), physicsClientId=client)
    return RobotModel(body=body, wheel_joints=wheels, caster_links=casters, axle_height=shape.axle_height)
