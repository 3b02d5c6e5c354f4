"""Dead reckoning from wheel angles: the OdometryRTC integration of docs/protocol.md section 5, pure.

No zenoh here. :class:`Odometry` holds the state between samples (last wheel angles and time,
last body speed, pose) and :meth:`Odometry.step` integrates one wheel-angle sample exactly as
docs/protocol.md writes it, with b = axle/2::

    vL = r_L·(qL − qL_old)/Δt          vR = r_R·(qR − qR_old)/Δt
    V  = (vR + vL)/2                   Ω  = (vR − vL)/(2b)
    Δφ = Ω·Δt                          θ  = wrap(θ_old + Δφ)
    if Δφ == 0:                      ΔL = (r_L·ΔqL + r_R·ΔqR)/2            straight
    else: ρ = b·(vR + vL)/(vR − vL)
          if |ρ| > RhoBorder:        ΔL = (r_L·ΔqL + r_R·ΔqR)/2, ρ clamped rho_border
          elif |Δφ| < RotationAngleBorder: ΔL = ρ·Δφ                      small_angle
          else:                      ΔL = 2ρ·sin(Δφ/2)                    chord
    x = x_old + ΔL·cos(θ_old + Δφ/2)    y = y_old + ΔL·sin(θ_old + Δφ/2)

The straight branches take the step's own mean wheel travel, exact whatever the speed and Δt
(a correction of the seed, whose trapezoid (V + V_old)/2·Δt lost half a step from rest, carried
the old speed across a reset and drifted when speed and Δt changed together; it remains as
``straight_step = "seed"``). The chord branch is exact for motion of constant curvature; the
small-angle branch takes arc length for chord, a relative error of at most
RotationAngleBorder²/24 (1.3e-5 at the default).

The first sample only initialises (the robot is taken to be at rest: V_old = 0, which only the
seed's trapezoid reads). A localized pose (:meth:`Odometry.reset`) overwrites (x_old, y_old,
θ_old) before the next step, and so does a pose set at runtime (:meth:`Odometry.set_pose`).
:meth:`Odometry.restart_time_base` (a restarted simulator, whose clock started again) makes the
next sample initialise again, keeping the pose. The hot path runs thousands of times a second:
plain floats, no allocation beyond the returned step.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from enum import StrEnum
from typing import NamedTuple

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND
from services.clock.sim_time import StampGap, check_stamp_near
from services.config import CalibratedGeometry, InputConfig, OdometryConfig, RobotConfig
from services.planar import Pose, check_coordinates, wrap_angle

__all__ = ["Branch", "Odometry", "Pose", "Step", "wrap_angle"]


class Branch(StrEnum):
    """Which formula a step took for ΔL (names used in the trace and in ``status``)."""

    INITIAL = "initial"
    """The first sample: nothing integrated, the pose is the starting pose."""
    STRAIGHT = "straight"
    """Δφ == 0: the mean wheel travel (or the seed's trapezoid of V and V_old)."""
    RHO_BORDER = "rho_border"
    """|ρ| > RhoBorder: as straight, ρ clamped to ±RhoBorder."""
    SMALL_ANGLE = "small_angle"
    """|Δφ| < RotationAngleBorder: arc length ρ·Δφ."""
    CHORD = "chord"
    """Otherwise: the exact chord 2ρ·sin(Δφ/2)."""


class Step(NamedTuple):
    """One integrated sample: its inputs, the intermediate values and the new pose.

    ``rho`` is None where the formula computes no ρ (initial, straight); clamped to ±RhoBorder in
    the rho_border branch. For the initial sample every rate and increment is 0.
    """

    branch: Branch
    q_left: float
    q_right: float
    dt: float
    v_left: float
    v_right: float
    v: float
    omega: float
    dphi: float
    rho: float | None
    dl: float
    x: float
    y: float
    theta: float

    @property
    def pose(self) -> Pose:
        return Pose(self.x, self.y, self.theta)


FIX_HISTORY_STEPS = 4096
"""Poses kept for fixes that arrive late: about 4 s of 1 ms steps."""
PENDING_POSES = 16
"""Poses stamped ahead of the last sample (fixes, set poses) that may wait for their stamps."""


class Odometry:
    """The integrator's state and its two inputs: wheel-angle samples and localized poses."""

    __slots__ = (
        "_angle_border",
        "_b",
        "_gap",
        "_history",
        "_horizon_ns",
        "_left_id",
        "_max_coordinate",
        "_max_wheel_speed",
        "_needed",
        "_omega",
        "_pending",
        "_q_left",
        "_q_right",
        "_r_left",
        "_r_right",
        "_rho_border",
        "_right_id",
        "_seed_straight",
        "_theta",
        "_time_ns",
        "_v",
        "_x",
        "_y",
        "config",
        "geometry",
        "robot",
    )

    def __init__(
        self,
        robot: RobotConfig,
        odometry: OdometryConfig,
        start: Pose = Pose(0.0, 0.0, 0.0),
        limits: InputConfig = InputConfig(),
    ) -> None:
        """Locked at activation: the robot's geometry, the odometry's
        parameters and the input limits."""
        self.robot, self.config = robot, odometry
        self.geometry = geometry = CalibratedGeometry.of(robot, odometry)
        self._horizon_ns = limits.stamp_horizon_ns
        self._gap = StampGap(limits.stamp_horizon_ns)
        self._max_wheel_speed = limits.max_wheel_speed
        self._max_coordinate = limits.max_coordinate
        self._left_id = robot.left_wheel_id
        self._right_id = robot.right_wheel_id
        self._needed = max(robot.left_wheel_id, robot.right_wheel_id) + 1
        self._r_left, self._r_right, self._b = geometry
        self._angle_border = odometry.rotation_angle_border
        self._rho_border = odometry.rho_border
        self._seed_straight = odometry.straight_step == "seed"
        self._time_ns: int | None = None
        self._q_left = self._q_right = 0.0
        self._v = self._omega = 0.0
        self._x, self._y, self._theta = 0.0, 0.0, 0.0
        self._history: deque[tuple[int, float, float, float]] = deque(maxlen=FIX_HISTORY_STEPS)
        self._pending: list[tuple[int, float, float, float]] = []
        """Poses stamped ahead of the last sample (fixes, set poses), in stamp order."""
        self.reset(*start)

    @property
    def initialised(self) -> bool:
        """True once the first wheel-angle sample has arrived."""
        return self._time_ns is not None

    @property
    def time_ns(self) -> int | None:
        """The stamp of the last sample integrated; None before the first (or a restart)."""
        return self._time_ns

    @property
    def pose(self) -> Pose:
        return Pose(self._x, self._y, self._theta)

    @property
    def velocity(self) -> tuple[float, float]:
        """(V, Ω) of the last step, in m/s and rad/s; (0, 0) before any step."""
        return self._v, self._omega

    def reset(self, x: float, y: float, theta: float) -> Pose:
        """Overwrite the pose with a localized one (θ wrapped); the next step starts from it.
        BadInput for a pose that is not finite or beyond ``input.max_coordinate``."""
        if not math.isfinite(theta):
            raise BadInput(f"pose ({x}, {y}, {theta}) is not finite")
        check_coordinates(x, y, self._max_coordinate)
        self._x, self._y, self._theta = x, y, wrap_angle(theta)
        return self.pose

    def reset_at(self, stamp_ns: int, x: float, y: float, theta: float) -> Pose:
        """Apply a localized pose taken at simulation time ``stamp_ns``.

        A fix stamped at the last sample's time is :meth:`reset` (docs/protocol.md section 5). Services run
        asynchronously, so a fix may instead arrive after odometry has integrated past its stamp,
        or before odometry has reached it. A past fix keeps the motion integrated since its stamp
        on top of it (overwriting would throw that motion away: the pose would jump back by
        speed × delay); a future fix (or one before any sample) waits, and replaces the pose
        integrated up to its stamp just before the first sample after it is integrated: the same
        pose as a fix that arrives right after that sample, so lockstep runs come out the same.

        BadInput (nothing changes) for a fix older than the history (:data:`FIX_HISTORY_STEPS`
        samples: applying it "now" would be wrong by all the motion since), further ahead than
        the stamp horizon, not plausible (:meth:`reset`), or beyond :data:`PENDING_POSES` waiting.
        """
        if not math.isfinite(theta):
            raise BadInput(f"pose ({x}, {y}, {theta}) is not finite")
        check_coordinates(x, y, self._max_coordinate)
        if self._time_ns is None:
            self._wait(stamp_ns, x, y, theta)
            return self.pose
        if stamp_ns == self._time_ns:
            return self.reset(x, y, theta)
        oldest_ns = self._history[0][0]
        check_stamp_near(stamp_ns, self._time_ns, self._horizon_ns, self._time_ns - oldest_ns, "fix")
        if stamp_ns > self._time_ns:
            self._wait(stamp_ns, x, y, theta)
            return self.pose
        base = next(entry for entry in reversed(self._history) if entry[0] <= stamp_ns)
        _t, base_x, base_y, base_theta = base
        cos_base, sin_base = math.cos(base_theta), math.sin(base_theta)
        dx, dy = self._x - base_x, self._y - base_y
        forward, left = cos_base * dx + sin_base * dy, -sin_base * dx + cos_base * dy
        cos_fix, sin_fix = math.cos(theta), math.sin(theta)
        return self.reset(
            x + cos_fix * forward - sin_fix * left,
            y + sin_fix * forward + cos_fix * left,
            theta + (self._theta - base_theta),
        )

    def set_pose(self, x: float, y: float, theta: float, stamp_ns: int | None = None) -> int | None:
        """Set the pose at runtime (diff_drive_controller's ``set_odometry``; a reset is (0, 0, 0)):
        as a localized pose stamped ``stamp_ns`` (:meth:`reset_at`), so that it lands on the same
        sample whenever it arrives; None stamps it with the last sample's time (before any sample:
        the starting pose). Returns the stamp it applies at (None: the starting pose). BadInput
        (nothing changes) as :meth:`reset_at`."""
        if stamp_ns is None:
            stamp_ns = self._time_ns
            if stamp_ns is None:
                self.reset(x, y, theta)
                return None
        self.reset_at(stamp_ns, x, y, theta)
        return stamp_ns

    def _wait(self, stamp_ns: int, x: float, y: float, theta: float) -> None:
        """Keep a pose stamped ahead until the first sample after its stamp; each applies in stamp
        order (one arriving later does not replace one due earlier). BadInput beyond
        :data:`PENDING_POSES` waiting."""
        if len(self._pending) >= PENDING_POSES:
            raise BadInput(f"{PENDING_POSES} poses already wait for their stamps")
        bisect.insort(self._pending, (stamp_ns, x, y, theta), key=lambda pending: pending[0])

    def restart_time_base(self) -> None:
        """Forget the last sample's time and angles: the next sample initialises, like the first.

        For a restarted simulator: its clock started again and its wheel angles belong to a new
        world. The pose is kept (the next localized pose corrects it); the robot is taken to be
        at rest again (V_old = 0).
        """
        self._time_ns = None
        self._v = self._omega = 0.0
        self._history.clear()
        self._pending.clear()

    def step(self, time_ns: int, wheel_angles: Sequence[float]) -> Step:
        """Integrate one sample taken at ``time_ns`` (nanoseconds); the wheels are picked by id.

        Raises BadInput (state unchanged) for a sequence too short for the wheel ids, a
        non-finite angle, Δt <= 0, or a step whose result would not be finite.
        """
        if len(wheel_angles) < self._needed:
            raise BadInput(
                f"{len(wheel_angles)} wheel angles, wheel ids {self._left_id} and {self._right_id} "
                f"need at least {self._needed}"
            )
        q_left = wheel_angles[self._left_id]
        q_right = wheel_angles[self._right_id]
        if not (math.isfinite(q_left) and math.isfinite(q_right)):
            raise BadInput(f"wheel angles ({q_left}, {q_right}) are not finite")
        pending = self._pending
        while pending and time_ns > pending[0][0]:
            self.reset(*pending.pop(0)[1:])
        if self._time_ns is None:
            self._time_ns, self._q_left, self._q_right = time_ns, q_left, q_right
            self._history.append((time_ns, self._x, self._y, self._theta))
            return Step(
                Branch.INITIAL, q_left, q_right, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, None, 0.0, self._x, self._y, self._theta
            )
        # After a gap (a link down) the stream is taken back and the step spans the gap.
        self._gap.check(time_ns, self._time_ns)
        dt = (time_ns - self._time_ns) / NANOSECONDS_PER_SECOND
        rate_left, rate_right = (q_left - self._q_left) / dt, (q_right - self._q_right) / dt
        if not (abs(rate_left) <= self._max_wheel_speed and abs(rate_right) <= self._max_wheel_speed):
            raise BadInput(
                f"wheel speeds ({rate_left:g}, {rate_right:g}) rad/s beyond input.max_wheel_speed = "
                f"{self._max_wheel_speed:g} rad/s"
            )
        b = self._b
        v_left = self._r_left * (q_left - self._q_left) / dt
        v_right = self._r_right * (q_right - self._q_right) / dt
        v = (v_right + v_left) / 2.0
        omega = (v_right - v_left) / (2.0 * b)
        dphi = omega * dt
        if not (math.isfinite(v) and math.isfinite(dphi)):
            raise BadInput(f"wheel angles ({q_left}, {q_right}) over dt = {dt} s give a non-finite speed")
        theta_old = self._theta
        rho: float | None
        if dphi == 0.0:
            branch, rho = Branch.STRAIGHT, None
            dl = self._straight_travel(q_left, q_right, v, dt)
        else:
            rho = b * (v_right + v_left) / (v_right - v_left)
            if abs(rho) > self._rho_border:
                branch, rho = Branch.RHO_BORDER, math.copysign(self._rho_border, rho)
                dl = self._straight_travel(q_left, q_right, v, dt)
            elif abs(dphi) < self._angle_border:
                branch = Branch.SMALL_ANGLE
                dl = rho * dphi
            else:
                branch = Branch.CHORD
                dl = 2.0 * rho * math.sin(dphi / 2.0)
        heading = theta_old + dphi / 2.0
        x = self._x + dl * math.cos(heading)
        y = self._y + dl * math.sin(heading)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise BadInput(f"wheel angles ({q_left}, {q_right}) over dt = {dt} s give a non-finite pose")
        theta = wrap_angle(theta_old + dphi)
        self._time_ns, self._q_left, self._q_right = time_ns, q_left, q_right
        self._v, self._omega = v, omega
        self._x, self._y, self._theta = x, y, theta
        self._history.append((time_ns, x, y, theta))
        return Step(branch, q_left, q_right, dt, v_left, v_right, v, omega, dphi, rho, dl, x, y, theta)

    def _straight_travel(self, q_left: float, q_right: float, v: float, dt: float) -> float:
        """ΔL of the straight branches: the mean wheel travel, or the seed's trapezoid."""
        if self._seed_straight:
            return (v + self._v) / 2.0 * dt
        return (self._r_left * (q_left - self._q_left) + self._r_right * (q_right - self._q_right)) / 2.0
