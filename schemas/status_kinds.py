"""Which Struct each service's status reply decodes as (:mod:`schemas.status`,
:mod:`schemas.drive_status`): a reader asks :func:`status_type` for a service's name, a recording
or a live view :func:`status_type_of_key` for a key (its channel's JSON schema)."""

from __future__ import annotations

from schemas.drive_status import DriveStatus, Ros2Status
from schemas.keys import CONTROL, VIEW, Service, parse_status_key, user_service_name
from schemas.status import (
    ControlStatus,
    LocalizationStatus,
    MotorStatus,
    OdometryStatus,
    Reply,
    ServiceStatus,
    SimStatus,
    UserServiceStatus,
    ViewStatus,
)

STATUS_TYPES: dict[str, type[ServiceStatus]] = {
    Service.SIM: SimStatus,
    Service.MOTOR: MotorStatus,
    Service.ODOMETRY: OdometryStatus,
    Service.LOCALIZATION: LocalizationStatus,
    Service.DRIVE: DriveStatus,
    Service.ROS2: Ros2Status,
}
"""The built-in services' kinds; any other name is a user service's."""


def status_type(service: str) -> type[ServiceStatus]:
    """The Struct ``service``'s status decodes as (a user service's common part for a name not built in)."""
    return STATUS_TYPES.get(service, UserServiceStatus)


def status_type_of_key(key: str) -> type[Reply] | None:
    """The Struct of the replies on ``key`` when it is a status key: its service's kind (a user
    service's common part for a name one may take), or ``invent view``'s or ``invent control``'s;
    None for any other key."""
    parsed = parse_status_key(key)
    if parsed is None:
        return None
    name = parsed[1]
    if name == VIEW:
        return ViewStatus
    if name == CONTROL:
        return ControlStatus
    if name in STATUS_TYPES:
        return STATUS_TYPES[name]
    try:
        user_service_name(name)
    except ValueError:
        return None  # no service can have this name: not a status key of the stack's
    return UserServiceStatus
