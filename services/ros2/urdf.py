"""The robot's URDF, generated from the body the simulator builds (:func:`services.body.geometry.robot_body`):
one source, so RViz's RobotModel shows what PyBullet simulates. Published on ``/robot_description``.

The root link is ``ros2.base_frame`` on the axle centre; the wheels are continuous joints about
+y at y = ±b (the joint names of ``/joint_states``); the casters fixed spheres; each sensor's frame
(``base_scan``, ``imu_link``) a link without geometry on a fixed joint at its mount, as TurtleBot3's
(the lidar sits in a slot of the body, which the body's cylinder already draws).
"""

from __future__ import annotations

import math
from xml.etree import ElementTree

from services.body.geometry import RobotBody
from services.ros2.sensors import SensorFrame

_BODY_COLOUR = "0.85 0.85 0.9 1"
_WHEEL_COLOUR = "0.15 0.15 0.15 1"


def _numbers(*values: float) -> str:
    return " ".join(f"{value:.9g}" for value in values)


def _inertial(parent: ElementTree.Element, mass: float, inertia: tuple[float, float, float], z: float = 0.0) -> None:
    inertial = ElementTree.SubElement(parent, "inertial")
    ElementTree.SubElement(inertial, "origin", xyz=_numbers(0.0, 0.0, z), rpy="0 0 0")
    ElementTree.SubElement(inertial, "mass", value=_numbers(mass))
    ixx, iyy, izz = inertia
    ElementTree.SubElement(
        inertial, "inertia", ixx=_numbers(ixx), iyy=_numbers(iyy), izz=_numbers(izz), ixy="0", ixz="0", iyz="0"
    )


def _shape(
    parent: ElementTree.Element,
    kind: str,
    geometry: tuple[str, dict[str, str]],
    xyz: str,
    rpy: str,
    colour: str | None = None,
) -> None:
    """A ``visual`` or ``collision`` of ``geometry`` (its tag and attributes) at ``xyz``, ``rpy``."""
    element = ElementTree.SubElement(parent, kind)
    ElementTree.SubElement(element, "origin", xyz=xyz, rpy=rpy)
    shape, attributes = geometry
    ElementTree.SubElement(ElementTree.SubElement(element, "geometry"), shape, attrib=attributes)
    if colour is not None:
        material = ElementTree.SubElement(element, "material", name=f"colour_{colour.replace(' ', '_')}")
        ElementTree.SubElement(material, "color", rgba=colour)


def robot_urdf(name: str, base_frame: str, body: RobotBody, sensors: tuple[SensorFrame, ...] = ()) -> str:
    """The URDF of ``body`` and its ``sensors`` as a string (``<robot name=...>``)."""
    robot = ElementTree.Element("robot", name=name)
    base = ElementTree.SubElement(robot, "link", name=base_frame)
    half_height = body.body_height / 2.0
    cylinder = ("cylinder", {"radius": _numbers(body.body_radius), "length": _numbers(body.body_height)})
    _shape(base, "visual", cylinder, _numbers(0.0, 0.0, half_height), "0 0 0", _BODY_COLOUR)
    _shape(base, "collision", cylinder, _numbers(0.0, 0.0, half_height), "0 0 0")
    _inertial(base, body.body_mass, body.body_inertia)
    for wheel in body.wheels:
        link = ElementTree.SubElement(robot, "link", name=wheel.link)
        disc = ("cylinder", {"radius": _numbers(wheel.radius), "length": _numbers(wheel.width)})
        _shape(link, "visual", disc, "0 0 0", _numbers(math.pi / 2.0, 0.0, 0.0), _WHEEL_COLOUR)
        _shape(link, "collision", ("sphere", {"radius": _numbers(wheel.radius)}), "0 0 0", "0 0 0")
        _inertial(link, wheel.mass, wheel.inertia)
        joint = ElementTree.SubElement(robot, "joint", name=wheel.joint, type="continuous")
        ElementTree.SubElement(joint, "parent", link=base_frame)
        ElementTree.SubElement(joint, "child", link=wheel.link)
        ElementTree.SubElement(joint, "origin", xyz=_numbers(0.0, wheel.y, 0.0), rpy="0 0 0")
        ElementTree.SubElement(joint, "axis", xyz="0 1 0")
    for caster in body.casters:
        link = ElementTree.SubElement(robot, "link", name=caster.link)
        ball = ("sphere", {"radius": _numbers(caster.radius)})
        _shape(link, "visual", ball, "0 0 0", "0 0 0", _WHEEL_COLOUR)
        _shape(link, "collision", ball, "0 0 0", "0 0 0")
        moment = 2.0 * caster.mass * caster.radius**2 / 5.0
        _inertial(link, caster.mass, (moment, moment, moment))
        joint = ElementTree.SubElement(robot, "joint", name=f"{caster.link}_joint", type="fixed")
        ElementTree.SubElement(joint, "parent", link=base_frame)
        ElementTree.SubElement(joint, "child", link=caster.link)
        ElementTree.SubElement(joint, "origin", xyz=_numbers(caster.x, 0.0, caster.z), rpy="0 0 0")
    for sensor in sensors:
        ElementTree.SubElement(robot, "link", name=sensor.frame)
        joint = ElementTree.SubElement(robot, "joint", name=sensor.joint, type="fixed")
        ElementTree.SubElement(joint, "parent", link=base_frame)
        ElementTree.SubElement(joint, "child", link=sensor.frame)
        ElementTree.SubElement(
            joint, "origin", xyz=_numbers(sensor.x, sensor.y, sensor.z), rpy=_numbers(0.0, 0.0, sensor.yaw)
        )
    ElementTree.indent(robot)
    return '<?xml version="1.0"?>\n' + ElementTree.tostring(robot, encoding="unicode") + "\n"
