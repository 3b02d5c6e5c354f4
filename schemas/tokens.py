"""Liveliness tokens' keys parsed back (docs/protocol.md section 2.5): who is alive, a lockstep
participant's ticks token (a built-in's, or a user service's naming its output), an observer's.
Their keys are built by :class:`schemas.keys.Keys`; the watchers read them here."""

from __future__ import annotations

import math
from dataclasses import dataclass

from schemas.keys import ALIVE, OBSERVES, ROOT, TICKS, Service, ServiceName, own_suffix_error, service_name
from schemas.topics import Topic


def _service_chunk(chunk: str) -> ServiceName | None:
    """The service a key's chunk names: a built-in, a valid user service name, or None."""
    try:
        return service_name(chunk)
    except ValueError:
        return None


def parse_alive_key(key: str) -> tuple[str, ServiceName] | None:
    """``invent/rh0/motor/alive`` -> ``("rh0", Service.MOTOR)`` (a user service's name as it is);
    None for any other key."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[3] != ALIVE:
        return None
    service = _service_chunk(parts[2])
    return None if service is None else (parts[1], service)


def parse_ticks_key(key: str) -> tuple[ServiceName, float] | None:
    """``invent/rh0/drive/ticks/50.0`` -> ``(Service.DRIVE, 50.0)``; None for any other key (a user
    participant's token, which names its output, is :func:`parse_participant_key`'s)."""
    return _parse_rate_key(key, TICKS)


def parse_observes_key(key: str) -> tuple[ServiceName, float] | None:
    """``invent/rh0/ros2/observes/50.0`` -> ``(Service.ROS2, 50.0)``; None for any other key."""
    return _parse_rate_key(key, OBSERVES)


@dataclass(frozen=True)
class Participant:
    """A lockstep participant as its ticks token names it: who, at what rate, and the key (relative
    to the robot) of the output the simulator waits for at each of its ticks."""

    service: ServiceName
    rate_hz: float
    output: str


def parse_participant_key(key: str, builtin_outputs: dict[Service, Topic]) -> Participant | None:
    """A participant's ticks token: a built-in's (``invent/rh0/drive/ticks/50.0``, its output from
    ``builtin_outputs``) or a user service's (``invent/rh0/odometer/ticks/10.0/distance``: its
    output ``odometer/distance``); None for any other key."""
    parts = key.split("/")
    if len(parts) < 5 or parts[0] != ROOT or parts[3] != TICKS:
        return None
    service = _service_chunk(parts[2])
    rate_hz = _rate(parts[4])
    if service is None or rate_hz is None:
        return None
    if isinstance(service, Service):
        output = builtin_outputs.get(service)
        return None if output is None or len(parts) != 5 else Participant(service, rate_hz, str(output))
    suffix = "/".join(parts[5:])
    if not suffix or own_suffix_error(suffix) is not None:
        return None
    return Participant(service, rate_hz, f"{service}/{suffix}")


def _rate(text: str) -> float | None:
    try:
        rate_hz = float(text)
    except ValueError:
        return None
    return rate_hz if math.isfinite(rate_hz) and rate_hz > 0.0 else None


def _parse_rate_key(key: str, kind: str) -> tuple[ServiceName, float] | None:
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[3] != kind:
        return None
    service = _service_chunk(parts[2])
    rate_hz = _rate(parts[4])
    if service is None or rate_hz is None:
        return None
    return service, rate_hz
