"""The localization stub of docs/protocol.md section 7, pure (no zenoh).

A :class:`Localizer` turns the stream of simulated poses (``motor/sim_pose/localization``:
x, y, z, θ stamped with simulation time) into localized fixes:

- the first sample publishes the configured initial pose, stamped with that sample's time t0,
  if t0 is within one fix period of simulation time 0 (the initial pose is the pose at the
  start); a later t0 means the simulator was already running (this service was restarted, or
  started late), and the first fix is then that sample's simulated pose, with noise: sending
  odometry back to the initial pose mid-run would be wrong by everything driven since;
- then one fix at every tick k/rate (k = 1, 2, ...) of simulation time after t0, taken by the
  first sample at or after the tick: that sample's pose plus Gaussian noise, independent per
  axis (σx, σy, σθ), θ wrapped into (−π, π]. The grid is anchored at time 0, not at t0, so a
  lockstep simulator knows the ticks from the rate alone (services/clock/lockstep.py).

When the simulator restarts (its token appeared, :attr:`Localizer.restart`, then a stamp not
after the last one: its clock started again), that sample starts a new time base and, once the schedule
runs, takes a fix at once (the simulated pose, with noise: not the initial pose again), then
one at every tick of the grid after it.

The noise comes from a seeded :class:`numpy.random.Generator`, so a run is repeatable.
"""

from __future__ import annotations

import math
import secrets
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.topics import SIM_POSE_LENGTH
from services.clock.sim_time import ClockRestart, PeriodicSchedule, StampClock
from services.config import Config, InputConfig
from services.planar import Pose, check_coordinates, wrap_angle

SEED_BITS = 63
"""Seeds drawn from the OS fit a signed 64-bit integer, so they can be passed back as ``seed``."""


@dataclass(frozen=True)
class Noise:
    """Standard deviations of the fix noise: x and y in m, θ in rad (0 = exact)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def __post_init__(self) -> None:
        for name, sigma in (("x", self.x), ("y", self.y), ("theta", self.theta)):
            if not (math.isfinite(sigma) and sigma >= 0.0):
                raise ValueError(f"noise σ{name} must be finite and >= 0, got {sigma}")


@dataclass(frozen=True)
class Fix:
    stamp_ns: int
    pose: Pose
    initial: bool
    """True for the configured initial pose (the first fix), False for a fix from the simulator."""


def resolve_seed(seed: int | None) -> int:
    """``seed``, or a fresh one from the OS when None (reported in status so a run can be repeated)."""
    return secrets.randbits(SEED_BITS) if seed is None else seed


class Localizer:
    """Fix schedule and noise; feed it every simulated pose with :meth:`on_sim_pose`."""

    def __init__(
        self,
        initial: Pose,
        rate_hz: float,
        noise: Noise,
        rng: np.random.Generator,
        limits: InputConfig = InputConfig(),
    ) -> None:
        self.initial = Pose(initial.x, initial.y, wrap_angle(initial.theta))
        self.rate_hz = rate_hz
        self.noise = noise
        self._initial_pose_until_ns = round(NANOSECONDS_PER_SECOND / rate_hz)
        self.first_fix_from_sim_pose: bool | None = None
        """Whether the first fix was the simulated pose (None before it)."""
        self._sigmas = (noise.x, noise.y, noise.theta)
        self._rng = rng
        self._max_coordinate = limits.max_coordinate
        self._clock = StampClock(limits.stamp_horizon_ns)
        self._schedule: PeriodicSchedule | None = None
        self.fixes = 0
        self.last_fix: Fix | None = None
        self.last_sim_pose: Pose | None = None

    @property
    def started(self) -> bool:
        """True once the initial pose has been published (the fix schedule runs)."""
        return self._schedule is not None

    @classmethod
    def from_config(cls, config: Config, seed: int) -> Localizer:
        localization = config.localization
        return cls(
            Pose(localization.initial_x, localization.initial_y, localization.initial_theta),
            localization.rate,
            Noise(localization.noise_x, localization.noise_y, localization.noise_theta),
            np.random.default_rng(seed),
            config.input,
        )

    @property
    def restart(self) -> ClockRestart:
        """Told when a simulator's token appears; the next stamp decides if it was restarted."""
        return self._clock.restart

    @property
    def time_base_restarts(self) -> int:
        return self._clock.restart.restarts

    def on_sim_pose(self, stamp_ns: int, data: Sequence[float], may_start: bool = True) -> Fix | None:
        """Take one simulated pose [x, y, z, θ]; return the fix it triggers, if any.

        With ``may_start`` False the pose is only recorded and the schedule (with the initial
        pose) does not start yet. Raises BadInput (state unchanged) for a wrong length or a
        stamp not after the previous one (unless it starts a new time base).
        """
        if len(data) != SIM_POSE_LENGTH:
            raise BadInput(f"expected {SIM_POSE_LENGTH} values (x, y, z, theta), got {len(data)}")
        x, y, _z, theta = data
        check_coordinates(x, y, self._max_coordinate)
        restarted = self._clock.advance(stamp_ns)
        self.last_sim_pose = Pose(x, y, theta)
        if self._schedule is None:
            if not may_start:
                return None
            self._schedule = PeriodicSchedule(self.rate_hz, 0)
        elif restarted:
            self._schedule = PeriodicSchedule(self.rate_hz, 0)
        if not self._schedule.due(stamp_ns):
            return None
        if self.fixes == 0:
            self.first_fix_from_sim_pose = stamp_ns > self._initial_pose_until_ns
        if self.fixes == 0 and not self.first_fix_from_sim_pose:
            fix = Fix(stamp_ns, self.initial, initial=True)
        else:
            fix = Fix(stamp_ns, self._noisy(self.last_sim_pose), initial=False)
        self.fixes += 1
        self.last_fix = fix
        return fix

    def _noisy(self, pose: Pose) -> Pose:
        dx, dy, dtheta = (float(value) for value in self._rng.normal(0.0, self._sigmas))
        return Pose(pose.x + dx, pose.y + dy, wrap_angle(pose.theta + dtheta))
