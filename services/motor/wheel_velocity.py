"""The motor's velocity output (``motor.output = "velocity"``, docs/motor.md): the wheel speed
targets a plant's own velocity loop follows. A target is taken by the first wheel-angle sample of
each period of ``motor.velocity_rate`` (a grid on the plant's clock, so a lockstep run takes the
same ones every time) and sent again until the next; a stop takes one at once. Pure: no zenoh."""

from __future__ import annotations

import math

from schemas.messages import NANOSECONDS_PER_SECOND


class WheelVelocityOutput:
    """Left and right wheel speed targets (rad/s), held between the ticks of ``rate_hz`` and never
    beyond ``max_wheel_speed`` (``input.max_wheel_speed``: what a plant refuses)."""

    def __init__(self, rate_hz: float, max_wheel_speed: float) -> None:
        self.period_ns = max(1, round(NANOSECONDS_PER_SECOND / rate_hz))
        self.max_wheel_speed = max_wheel_speed
        self.targets: tuple[float, float] = (0.0, 0.0)
        """The targets sent with the latest sample."""
        self._period: int | None = None
        """The grid period whose target :attr:`targets` holds; None: the next sample takes one."""

    def rest(self) -> None:
        """Zero targets now; the next :meth:`follow` takes a new target wherever it falls on the grid."""
        self.targets = (0.0, 0.0)
        self._period = None

    def follow(self, stamp_ns: int, left: float, right: float, now: bool = False) -> tuple[float, float] | None:
        """The targets for the sample at ``stamp_ns`` when the control law asks for wheel speeds
        ``left``, ``right``: those, if the sample is its period's first (or ``now``), else the held
        ones. Both are scaled down together to ``max_wheel_speed`` (the curve is kept, the speed
        not). None for a non-finite request: the targets rest at zero."""
        period = stamp_ns // self.period_ns
        if not (now or period != self._period):
            return self.targets
        fastest = max(abs(left), abs(right))
        if not math.isfinite(fastest):
            self.rest()
            return None
        if fastest > self.max_wheel_speed:
            scale = self.max_wheel_speed / fastest
            left, right = left * scale, right * scale
        self._period = period
        self.targets = (left, right)
        return self.targets
