"""The four message types of SPEC section 1, mirroring the seeds' IDL field for field.

Every float must be finite: a Struct checks it in ``__post_init__``, which msgspec also
runs while decoding, so a NaN or inf can neither be built nor received.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

NANOSECONDS_PER_SECOND = 1_000_000_000

Seconds = Annotated[int, msgspec.Meta(ge=0)]
Nanoseconds = Annotated[int, msgspec.Meta(ge=0, lt=NANOSECONDS_PER_SECOND)]

MAX_SEQUENCE_LENGTH = 32
"""The most values a TimedDoubleSeq carries: a robot's joints (wheel angles, torques), the 12 of a
body pose. Longer is bad input, refused while decoding: a 10^6-element array must not be
decoded, checked and republished."""
MAX_ID_LENGTH = 16
"""The most entries of the IIS messages' ``id`` and ``error`` arrays (unused by the services)."""
DoubleSeq = Annotated[list[float], msgspec.Meta(max_length=MAX_SEQUENCE_LENGTH)]
Ids = Annotated[list[int], msgspec.Meta(max_length=MAX_ID_LENGTH)]
Errors = Annotated[list[float], msgspec.Meta(max_length=MAX_ID_LENGTH)]


def _require_finite(*values: float) -> None:
    for value in values:
        if not math.isfinite(value):
            raise ValueError(f"non-finite number {value!r}")


class Time(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """RTC::Time: a timestamp in whole seconds and nanoseconds."""

    sec: Seconds
    nsec: Nanoseconds

    @classmethod
    def from_seconds(cls, seconds: float) -> Time:
        total_ns = round(seconds * NANOSECONDS_PER_SECOND)
        return cls(*divmod(total_ns, NANOSECONDS_PER_SECOND))

    @classmethod
    def from_nanoseconds(cls, total_ns: int) -> Time:
        return cls(*divmod(total_ns, NANOSECONDS_PER_SECOND))

    def to_seconds(self) -> float:
        return self.sec + self.nsec / NANOSECONDS_PER_SECOND

    def to_nanoseconds(self) -> int:
        return self.sec * NANOSECONDS_PER_SECOND + self.nsec


class TimedDoubleSeq(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """RTC::TimedDoubleSeq."""

    tm: Time
    data: DoubleSeq

    def __post_init__(self) -> None:
        _require_finite(*self.data)


class TimedVelocity(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """IIS::TimedVelocity: target body velocity (vx, vy in m/s, w in rad/s)."""

    tm: Time
    id: Ids
    vx: float
    vy: float
    w: float
    error: Errors

    def __post_init__(self) -> None:
        _require_finite(self.vx, self.vy, self.w, *self.error)


class TimedPosition(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """IIS::TimedPosition: a planar pose (x, y in m, theta in rad)."""

    tm: Time
    id: Ids
    x: float
    y: float
    theta: float
    error: Errors

    def __post_init__(self) -> None:
        _require_finite(self.x, self.y, self.theta, *self.error)


class BumpEvent(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``sim/bump``: the robot body began a contact with an obstacle (project extension).

    ``x, y, z`` is the contact point in the world frame, ``tm`` the simulation time.
    """

    tm: Time
    obstacle: str
    x: float
    y: float
    z: float

    def __post_init__(self) -> None:
        _require_finite(self.x, self.y, self.z)


NonNegativeGain = Annotated[float, msgspec.Meta(ge=0.0)]


class PDGains(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of the Motor interface's ``set_pd_gain``: all four gains, each finite and >= 0."""

    p_gain_l: NonNegativeGain
    p_gain_r: NonNegativeGain
    d_gain_l: NonNegativeGain
    d_gain_r: NonNegativeGain

    def __post_init__(self) -> None:
        _require_finite(self.p_gain_l, self.p_gain_r, self.d_gain_l, self.d_gain_r)


class NoArguments(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of the argument-less Motor methods: ``{}`` (an empty payload is accepted too)."""


MESSAGE_TYPES: tuple[type[msgspec.Struct], ...] = (
    Time,
    TimedDoubleSeq,
    TimedVelocity,
    TimedPosition,
    BumpEvent,
    PDGains,
    NoArguments,
)
