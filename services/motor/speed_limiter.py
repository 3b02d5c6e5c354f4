"""The limits on the commanded body velocity, as ROS 2's diff_drive_controller has them (its
``speed_limiter.hpp`` over control_toolbox's ``RateLimiter``): pure, one call per control cycle.

Each of vx and w has a :class:`SpeedLimiter`: a velocity range, an acceleration range that depends
on the direction of motion (forward or at rest, backward), and a jerk range, applied in
RateLimiter::limit's order: jerk, acceleration, velocity. Limits are magnitudes here (all
positive); the upstream parameters they mirror, with their signs, are in docs/motor.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from services.config import MotorConfig

SPEED_LIMIT_FIELDS = {
    "vx": (
        "max_vx",
        "max_vx_reverse",
        "max_ax",
        "max_ax_reverse",
        "max_decel_x",
        "max_decel_x_reverse",
        "max_jerk_x",
        "max_jerk_x_falling",
    ),
    "w": (
        "max_w",
        "max_w_reverse",
        "max_aw",
        "max_aw_reverse",
        "max_decel_w",
        "max_decel_w_reverse",
        "max_jerk_w",
        "max_jerk_w_falling",
    ),
}
"""``[motor]``'s limits of each speed, in :class:`SpeedLimiter`'s argument order."""


@dataclass(frozen=True)
class SpeedLimiter:
    """Velocity, acceleration and jerk limits on one commanded speed, as control_toolbox's RateLimiter.

    None disables a limit. A limit left None beside its base takes the base's value, as upstream
    takes NaN: ``max_velocity_reverse`` is ``max_velocity``; ``max_acceleration_reverse`` is
    ``max_acceleration``; ``max_deceleration`` is ``max_acceleration_reverse`` (as resolved);
    ``max_deceleration_reverse`` is ``max_acceleration``; ``max_jerk_falling`` is ``max_jerk``.
    With the base None the whole group is off (the configuration refuses the others set then).
    """

    max_velocity: float | None = None
    """The fastest the speed may be, positive."""
    max_velocity_reverse: float | None = None
    """The fastest it may be negative (backward, or clockwise), as a magnitude."""
    max_acceleration: float | None = None
    """How fast it may rise from rest or while positive (speeding up forward)."""
    max_acceleration_reverse: float | None = None
    """How fast it may fall from rest or while negative (speeding up backward)."""
    max_deceleration: float | None = None
    """How fast it may fall while positive (slowing down forward)."""
    max_deceleration_reverse: float | None = None
    """How fast it may rise while negative (slowing down backward)."""
    max_jerk: float | None = None
    """How fast its rate of rise may grow, while it rises."""
    max_jerk_falling: float | None = None
    """How fast its rate of fall may grow, while it falls."""
    _velocity: tuple[float, float] | None = field(init=False, repr=False, compare=False)
    """(lowest, highest) speed."""
    _acceleration: tuple[tuple[float, float], ...] | None = field(init=False, repr=False, compare=False)
    """(lowest, highest) rate of change while positive, while negative, at rest."""
    _jerk: tuple[float, float] | None = field(init=False, repr=False, compare=False)
    """(lowest, highest) growth of the rate of change, per s²."""

    @classmethod
    def of(cls, motor: MotorConfig, speed: str) -> SpeedLimiter:
        """The limiter of ``speed`` (``"vx"`` or ``"w"``) from ``[motor]``."""
        return cls(*(getattr(motor, name) for name in SPEED_LIMIT_FIELDS[speed]))

    def __post_init__(self) -> None:
        velocity: tuple[float, float] | None = None
        acceleration: tuple[tuple[float, float], ...] | None = None
        jerk: tuple[float, float] | None = None
        if self.max_velocity is not None:
            velocity = (-_or(self.max_velocity_reverse, self.max_velocity), self.max_velocity)
        if self.max_acceleration is not None:
            rising = self.max_acceleration
            falling = _or(self.max_acceleration_reverse, rising)
            forward = (-_or(self.max_deceleration, falling), rising)
            backward = (-falling, _or(self.max_deceleration_reverse, rising))
            acceleration = (forward, backward, (-falling, rising))
        if self.max_jerk is not None:
            jerk = (-_or(self.max_jerk_falling, self.max_jerk), self.max_jerk)
        object.__setattr__(self, "_velocity", velocity)
        object.__setattr__(self, "_acceleration", acceleration)
        object.__setattr__(self, "_jerk", jerk)

    @property
    def enabled(self) -> bool:
        return self.max_velocity is not None or self.max_acceleration is not None or self.max_jerk is not None

    def limit(self, value: float, previous: float, before_previous: float, dt: float) -> float:
        """``value`` limited against the last two commands (``previous``, then ``before_previous``)
        over the cycle's ``dt``: jerk, then acceleration, then velocity (RateLimiter::limit). A limit
        that does not bind returns ``value`` itself, bit for bit."""
        jerk = self._jerk
        if jerk is not None:
            change, previous_change = value - previous, previous - before_previous
            growth = change - previous_change
            # Only while the rate grows in the direction of the change (control_toolbox issue 240:
            # limiting the other way makes the closed loop oscillate).
            if growth * change > 0.0:
                dt2 = dt * dt
                low, high = jerk[0] * dt2, jerk[1] * dt2
                if growth < low or growth > high:
                    value = previous + previous_change + min(max(growth, low), high)
        acceleration = self._acceleration
        if acceleration is not None:
            forward, backward, at_rest = acceleration
            low, high = forward if previous > 0.0 else backward if previous < 0.0 else at_rest
            value = min(max(value, previous + low * dt), previous + high * dt)
        velocity = self._velocity
        if velocity is not None:
            value = min(max(value, velocity[0]), velocity[1])
        return value


def _or(value: float | None, default: float) -> float:
    return default if value is None else value


def limits_status(motor: MotorConfig) -> dict[str, Any]:
    """Every limit of ``[motor]`` by name, for the motor's status."""
    return {name: getattr(motor, name) for names in SPEED_LIMIT_FIELDS.values() for name in names}
