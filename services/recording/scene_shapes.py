"""The Foxglove primitives the scene's drawings are made of (pure, no zenoh): stamps, quaternions,
poses, lines over the ground, and the robot's body as the sim builds it
(services/body/geometry.py); for :mod:`services.recording.scene` and the drawings beside it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from foxglove.messages import (
    Color,
    CylinderPrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from schemas.messages import Time
from services.body.geometry import robot_body
from services.config import RobotConfig, SimConfig

_BODY = Color(r=0.85, g=0.85, b=0.9, a=0.8)
_WHEEL = Color(r=0.15, g=0.15, b=0.15, a=1.0)
UPRIGHT = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_WHEEL_AXIS_ALONG_Y = Quaternion(x=math.sqrt(0.5), y=0.0, z=0.0, w=math.sqrt(0.5))


def timestamp(tm: Time) -> Timestamp:
    return Timestamp(tm.sec, tm.nsec)


def yaw_quaternion(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))


def rotation_quaternion(m: list[float]) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a row-major 3x3 rotation matrix (Shepperd's method: stable for any rotation)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        return (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s
    if m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        return 0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s
    if m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        return (m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s
    s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
    return (m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s


def foxglove_pose(x: float, y: float, z: float, orientation: Quaternion = UPRIGHT) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=orientation)


def ground_line(
    points: Iterable[tuple[float, float]],
    color: Color,
    thickness: float,
    z: float = 0.01,
    kind: LinePrimitiveLineType = LinePrimitiveLineType.LineStrip,
) -> LinePrimitive:
    """A line drawn over the ground of its frame through ``points`` (x, y), ``z`` up (a trail's 1 cm)."""
    return LinePrimitive(
        type=kind,
        pose=foxglove_pose(0.0, 0.0, 0.0),
        thickness=thickness,
        points=[Point3(x=x, y=y, z=z) for x, y in points],
        color=color,
    )


def robot_entity(robot: RobotConfig, sim: SimConfig) -> dict[str, Any]:
    """The robot's primitives in ``base_link`` (the axle centre, at axle height), as the sim builds it."""
    shape = robot_body(robot, sim)
    body_diameter = 2.0 * shape.body_radius
    wheels = [
        CylinderPrimitive(
            pose=foxglove_pose(0.0, wheel.y, 0.0, _WHEEL_AXIS_ALONG_Y),
            size=Vector3(x=2.0 * wheel.radius, y=2.0 * wheel.radius, z=wheel.width),
            bottom_scale=1.0,
            top_scale=1.0,
            color=_WHEEL,
        )
        for wheel in shape.wheels
    ]
    body = CylinderPrimitive(
        pose=foxglove_pose(0.0, 0.0, shape.body_height / 2.0),
        size=Vector3(x=body_diameter, y=body_diameter, z=shape.body_height),
        bottom_scale=1.0,
        top_scale=1.0,
        color=_BODY,
    )
    casters = [
        SpherePrimitive(
            pose=foxglove_pose(caster.x, 0.0, caster.z),
            size=Vector3(x=2 * caster.radius, y=2 * caster.radius, z=2 * caster.radius),
            color=_WHEEL,
        )
        for caster in shape.casters
    ]
    return {"cylinders": [body, *wheels], "spheres": casters}
