"""The limits on one commanded speed, as ROS 2's diff_drive_controller has them in its own
``speed_limiter.hpp``: pure, one call per control cycle and speed."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SpeedLimiter:
    """Velocity and acceleration limits on one commanded speed, as in ROS 2's diff_drive_controller.

    The acceleration limit is applied first, then the velocity limit (SpeedLimiter::limit's order).
    None disables a limit.
    """

    max_velocity: float | None = None
    max_acceleration: float | None = None

    @property
    def enabled(self) -> bool:
        return self.max_velocity is not None or self.max_acceleration is not None

    def limit(self, value: float, previous: float, dt: float) -> float:
        if self.max_acceleration is not None:
            step = self.max_acceleration * dt
            value = min(max(value, previous - step), previous + step)
        if self.max_velocity is not None:
            value = min(max(value, -self.max_velocity), self.max_velocity)
        return value
