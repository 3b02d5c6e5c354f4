"""Who a session of a secure deployment is: the roles, and in a fleet the identities (a role, and
for a per-robot role the robot it is for)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum

from schemas.keys import Service, validate_robot_name


class Role(StrEnum):
    """Who a session is. The services, the control path composed in one process, and the roles of
    people and their tools."""

    SIM = Service.SIM.value
    MOTOR = Service.MOTOR.value
    ODOMETRY = Service.ODOMETRY.value
    LOCALIZATION = Service.LOCALIZATION.value
    DRIVE = Service.DRIVE.value
    ROS2 = Service.ROS2.value
    """The ROS 2 bridge: its ROS keys, ``drive/target_velocity``, the Motor methods ROS calls, and
    sending and canceling its robot's goals (``drive/goal/send``, ``drive/goal/cancel``)."""
    ROS_NODE = "ros_node"
    """A ROS 2 node over rmw_zenoh (RViz, teleop, Nav2): anything in the ROS domain, reading ours."""
    OPERATOR = "operator"
    """Teleop or GUI: puts target velocities, calls the Motor methods (``motor/gui/*``), sends and
    cancels goals (``invent goto``: ``drive/goal/send``, ``drive/goal/cancel``); and ``invent up``
    itself, which puts the run's summary (``up/run``) at the end of a run."""
    OBSERVER = "observer"
    """Watches: subscribes, gets ``status`` and liveliness, nothing else (no goals)."""
    CONTROL = "control"
    """The control path composed in one process (``invent control``: the sim and the motor on one
    session): what the sim and the motor are granted, together. One robot's only: a fleet's sim is
    fleet-wide and each robot's motor its own, so a fleet has no control role."""


PER_ROBOT_ROLES: tuple[Role, ...] = (Role.MOTOR, Role.ODOMETRY, Role.LOCALIZATION, Role.DRIVE, Role.ROS2)
"""In a fleet, each robot has its own user of each of these roles, allowed only that robot's keys."""
SINGLE_ROBOT_ROLES: tuple[Role, ...] = (Role.CONTROL,)
"""Roles only a single robot's profile has: the control path (the sim and the motor on one session)
is one robot's, since a fleet's sim steps every robot while each robot has its own motor."""
FLEET_ROLES: tuple[Role, ...] = tuple(
    role for role in Role if role not in PER_ROBOT_ROLES and role not in SINGLE_ROBOT_ROLES
)
"""In a fleet, one user each for the whole fleet: the sim (one simulator steps every robot), ROS 2
nodes, the operator (``invent up`` among them) and the observer, each allowed on every robot what
its role is allowed on one. Not :data:`SINGLE_ROBOT_ROLES`: a fleet has no control role."""


@dataclass(frozen=True)
class Identity:
    """Who a session logs in as: a role, and in a fleet the robot a per-robot role is for."""

    role: Role
    robot: str | None = None
    """None: a fleet-wide role, or any role of a single robot's profile."""

    @property
    def user(self) -> str:
        """The usrpwd user name, and the client file's name (``<user>.json5``): the role's name, or
        ``<robot>-<role>`` (``rh1-motor``). No role's name holds a ``-``, so the last ``-`` splits a
        user back into robot and role, and no two identities share a user or a file."""
        return str(self.role) if self.robot is None else f"{self.robot}-{self.role}"


def fleet_robots(robots: Iterable[str]) -> tuple[str, ...]:
    """``robots`` as a fleet: at least one, each a valid robot name (one key chunk), none twice;
    ValueError naming the first that is not."""
    fleet: list[str] = []
    for robot in robots:
        validate_robot_name(robot)
        if robot in fleet:
            raise ValueError(f"robot {robot!r} is named twice")
        fleet.append(robot)
    if not fleet:
        raise ValueError("a fleet has at least one robot")
    return tuple(fleet)


def fleet_identities(robots: Sequence[str]) -> tuple[Identity, ...]:
    """Every user of a fleet's profile: the fleet-wide roles, then each robot's per-robot roles
    (never :data:`SINGLE_ROBOT_ROLES`)."""
    return (
        *(Identity(role) for role in FLEET_ROLES),
        *(Identity(role, robot) for robot in robots for role in PER_ROBOT_ROLES),
    )
