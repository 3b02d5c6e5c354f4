"""Which Struct each service's status reply decodes as (:mod:`schemas.status`,
:mod:`schemas.drive_status`): a reader asks :func:`status_type` for a service's name."""

from __future__ import annotations

from schemas.drive_status import DriveStatus, Ros2Status
from schemas.keys import Service
from schemas.status import (
    LocalizationStatus,
    MotorStatus,
    OdometryStatus,
    ServiceStatus,
    SimStatus,
    UserServiceStatus,
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
