"""The drive of a diff-drive robot without physics engine: two wheels, each a motor turning an
inertia against a viscous loss, coupled by ideal rolling (no slip), the body following the wheels.
Pure: stdlib and numpy, no PyBullet, no zenoh. :mod:`sim_bridge.kinematic` builds its engine on it,
and an emulated motor controller can drive it too.

The model (docs/sim.md, "Engines"): with wheel angles φ = (φ_L, φ_R), radii r_L, r_R and half axle
b, ideal rolling gives the body's speed and turn rate

    v = (r_L φ̇_L + r_R φ̇_R) / 2,        ω = (r_R φ̇_R − r_L φ̇_L) / (2 b),

so the kinetic energy ½ m v² + ½ I ω² + ½ J (φ̇_L² + φ̇_R²) (m the whole robot's mass, I its
inertia about the vertical through the axle centre, J one wheel's spin inertia) is ½ φ̇ᵀ M φ̇ with

    M = [[m r_L²/4 + I r_L²/(4b²) + J,   m r_L r_R/4 − I r_L r_R/(4b²)],
         [m r_L r_R/4 − I r_L r_R/(4b²),  m r_R²/4 + I r_R²/(4b²) + J ]],

and the wheels' torques τ (saturated at ``max_torque``) against a viscous loss c per wheel give

    M φ̈ = τ − c φ̇.

For a torque held over a step this is linear with constant coefficients: :class:`DiffDrivePlant`
integrates it exactly (matrix exponential of −c M⁻¹ dt), so the result does not depend on how a
span is cut into steps beyond the torques' own changes. The pose follows each step's wheel travel
as an arc of constant curvature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt

from services.body.geometry import robot_body
from services.config import RobotConfig, SimConfig

Array = npt.NDArray[np.float64]

DEFAULT_WHEEL_DAMPING = 0.0
"""N·m·s/rad of viscous loss per wheel: none, as PyBullet's wheels have none. Measured in the real
:class:`~sim_bridge.simulator.Simulator` (default robot, 1 ms steps, docs/sim.md "Engines"): a held
1 N·m on both wheels gives 4.175, 8.342, 16.667 rad/s at 0.5, 1, 2 s, a constant acceleration; this
model gives 4.167, 8.333, 16.667 with c = 0, but 15.35 at 2 s with c = 0.01 and 11.31 with
c = 0.05. A real base's losses can be set with ``damping``."""


@dataclass(frozen=True)
class DriveModel:
    """What a wheel's torque drives: the wheels' geometry, the robot's mass and yaw inertia as the
    wheels see them, the wheels' own spin inertia and losses, and the torque limit."""

    left_radius: float
    right_radius: float
    half_axle: float
    mass: float
    """kg, the whole robot (body, wheels, casters)."""
    yaw_inertia: float
    """kg·m², the whole robot about the vertical through the axle centre."""
    wheel_inertia: float
    """kg·m², one wheel about its axle."""
    damping: float = DEFAULT_WHEEL_DAMPING
    """N·m·s/rad, each wheel's viscous loss (≥ 0)."""
    max_torque: float = math.inf
    """N·m, each wheel's torque limit."""

    def __post_init__(self) -> None:
        for name in ("left_radius", "right_radius", "half_axle", "mass", "yaw_inertia", "max_torque"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"DriveModel.{name} must be > 0, not {getattr(self, name)}")
        if not (self.wheel_inertia >= 0.0 and self.damping >= 0.0):
            raise ValueError("DriveModel.wheel_inertia and damping must be >= 0")

    @classmethod
    def from_description(cls, robot: RobotConfig, sim: SimConfig, damping: float = DEFAULT_WHEEL_DAMPING) -> DriveModel:
        """The drive of the robot the simulator builds (:func:`services.body.geometry.robot_body`):
        the same masses and inertias PyBullet is given, summed about the axle centre."""
        body = robot_body(robot, sim)
        mass = body.body_mass + sum(w.mass for w in body.wheels) + sum(c.mass for c in body.casters)
        yaw = body.body_inertia[2]
        yaw += sum(w.inertia[2] + w.mass * w.y**2 for w in body.wheels)
        yaw += sum(0.4 * c.mass * c.radius**2 + c.mass * c.x**2 for c in body.casters)
        left, right = body.wheels
        return cls(
            left_radius=left.radius,
            right_radius=right.radius,
            half_axle=robot.half_axle,
            mass=mass,
            yaw_inertia=yaw,
            wheel_inertia=left.inertia[1],
            damping=damping,
            max_torque=sim.max_wheel_torque,
        )

    @cached_property
    def mass_matrix(self) -> Array:
        """M, the 2×2 inertia the wheels' torques see (module docstring)."""
        rl, rr, b = self.left_radius, self.right_radius, self.half_axle
        m, inertia, j = self.mass, self.yaw_inertia, self.wheel_inertia
        turn = inertia / (4.0 * b * b)
        return np.array(
            [
                [m * rl * rl / 4.0 + turn * rl * rl + j, m * rl * rr / 4.0 - turn * rl * rr],
                [m * rl * rr / 4.0 - turn * rl * rr, m * rr * rr / 4.0 + turn * rr * rr + j],
            ]
        )

    def body_velocity(self, left_rate: float, right_rate: float) -> tuple[float, float]:
        """(v, ω) of the body for wheel rates in rad/s."""
        rl, rr = self.left_radius * left_rate, self.right_radius * right_rate
        return (rl + rr) / 2.0, (rr - rl) / (2.0 * self.half_axle)

    def kinetic_energy(self, left_rate: float, right_rate: float) -> float:
        rates = np.array([left_rate, right_rate])
        return float(0.5 * rates @ self.mass_matrix @ rates)

    def saturate(self, torque: float) -> float:
        limit = self.max_torque
        return min(max(torque, -limit), limit)

    def step_matrices(self, dt: float) -> StepMatrices:
        return StepMatrices.of(self, dt)


@dataclass(frozen=True)
class StepMatrices:
    """One step of ``dt`` of M φ̈ = τ − c φ̇ with τ held: φ̇₁ = Φ φ̇₀ + G τ and
    φ₁ = φ₀ + P φ̇₀ + Q τ (exact; c = 0 is the limit c → 0)."""

    rate_from_rate: Array
    rate_from_torque: Array
    angle_from_rate: Array
    angle_from_torque: Array
    torque_to_rest: Array
    """K such that τ = −K φ̇₀ brings φ̇₁ to 0."""
    torque_to_rate: Array
    """G⁻¹: τ = G⁻¹ φ̇₁ − K φ̇₀ brings φ̇₁ to the target φ̇₁ (a velocity loop's step, the brakes' at 0)."""

    @classmethod
    def of(cls, model: DriveModel, dt: float) -> StepMatrices:
        if not dt > 0.0:
            raise ValueError(f"a step of {dt} s")
        c = model.damping
        # M is symmetric positive definite: M = V diag(λ) Vᵀ, and A = c M⁻¹ = V diag(c/λ) Vᵀ
        eigenvalues, vectors = np.linalg.eigh(model.mass_matrix)
        rates = c / eigenvalues  # 1/s, the two modes' decay rates
        decay = np.exp(-rates * dt)
        # ∫₀^dt e^{-a s} ds and ∫₀^dt ∫₀^s e^{-a u} du ds, written to stay exact as a → 0
        once = np.array([dt * _phi1(a * dt) for a in rates])
        twice = np.array([dt * dt * _phi2(a * dt) for a in rates])
        inverse_mass = 1.0 / eigenvalues

        def matrix(diagonal: Array) -> Array:
            result: Array = (vectors * diagonal) @ vectors.T
            return result

        rate_from_torque = matrix(once * inverse_mass)
        torque_to_rate = np.asarray(np.linalg.inv(rate_from_torque), dtype=np.float64)
        return cls(
            rate_from_rate=matrix(decay),
            rate_from_torque=rate_from_torque,
            angle_from_rate=matrix(once),
            angle_from_torque=matrix(twice * inverse_mass),
            torque_to_rest=np.asarray(np.linalg.solve(rate_from_torque, matrix(decay)), dtype=np.float64),
            torque_to_rate=torque_to_rate,
        )


Row = tuple[float, float, float, float]


@dataclass(frozen=True)
class _Coefficients:
    """:class:`StepMatrices` as plain floats, row-major: what :meth:`DiffDrivePlant.step` multiplies."""

    rate_from_rate: Row
    rate_from_torque: Row
    angle_from_rate: Row
    angle_from_torque: Row
    torque_to_rest: Row
    torque_to_rate: Row

    @classmethod
    def of(cls, matrices: StepMatrices) -> _Coefficients:
        def row(matrix: Array) -> Row:
            (a, b), (c, d) = matrix.tolist()
            return a, b, c, d

        return cls(
            row(matrices.rate_from_rate),
            row(matrices.rate_from_torque),
            row(matrices.angle_from_rate),
            row(matrices.angle_from_torque),
            row(matrices.torque_to_rest),
            row(matrices.torque_to_rate),
        )


def _phi1(x: float) -> float:
    """(1 − e^{−x}) / x, 1 at 0."""
    return 1.0 if x == 0.0 else -math.expm1(-x) / x


def _phi2(x: float) -> float:
    """(x − 1 + e^{−x}) / x², ½ at 0."""
    # below 1e-3 the series (its error < x⁴/720) is closer than the cancelling difference
    return 0.5 - x / 6.0 + x * x / 24.0 - x**3 / 120.0 if abs(x) < 1e-3 else (x + math.expm1(-x)) / (x * x)


@dataclass
class DiffDrivePlant:
    """One robot's drive and pose on the floor: :meth:`step` applies the wheels' torques (saturated
    at the model's limit) for ``dt``, :meth:`brake` makes the next step brake the wheels to rest
    instead, each wheel's torque at most the limit (as a motor driver's brake, and as
    :meth:`sim_bridge.simulator.SimulatedRobot.brake`), and :meth:`follow` makes it bring them to
    target speeds the same way (a motor driver's velocity loop). Deterministic: the same calls give
    the same floats."""

    model: DriveModel
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    wheel_angles: tuple[float, float] = (0.0, 0.0)
    """Left, right, rad, unwrapped."""
    wheel_velocities: tuple[float, float] = (0.0, 0.0)
    """Left, right, rad/s."""
    braking: bool = False
    """The next :meth:`step` brakes to rest (its torques are ignored); cleared by that step."""
    target: tuple[float, float] | None = None
    """Wheel speeds (rad/s) the next :meth:`step` brings the wheels to, within the torque limit
    (its torques are ignored); cleared by that step. None: the torques apply."""
    applied: tuple[float, float] = (0.0, 0.0)
    """The torques the latest step applied (after saturation, or the brakes')."""
    _steps: dict[float, _Coefficients] = field(default_factory=dict, repr=False)

    def brake(self) -> None:
        self.braking = True

    def follow(self, left_rate: float, right_rate: float) -> None:
        """The next step's torques are those that bring the wheels to these speeds (rad/s) by its
        end, each at most the limit: what a velocity loop as fast as the step would apply."""
        self.target = (left_rate, right_rate)

    def step(self, left_torque: float, right_torque: float, dt: float) -> None:
        """Advance ``dt`` s with the wheels' torques held (or braking, after :meth:`brake`)."""
        step = self._steps.get(dt)
        if step is None:
            step = self._steps[dt] = _Coefficients.of(StepMatrices.of(self.model, dt))
        # plain floats, not numpy: a 2×2 product in numpy costs a microsecond, and this runs every step
        vl, vr = self.wheel_velocities
        limit = self.model.max_torque
        target = (0.0, 0.0) if self.braking else self.target
        reached = False
        if target is not None:
            k, h = step.torque_to_rest, step.torque_to_rate
            goal_l, goal_r = target
            needed_l = h[0] * goal_l + h[1] * goal_r - (k[0] * vl + k[1] * vr)
            needed_r = h[2] * goal_l + h[3] * goal_r - (k[2] * vl + k[3] * vr)
            tl, tr = min(max(needed_l, -limit), limit), min(max(needed_r, -limit), limit)
            # within the limit, the wheels reach the target in this step: exactly, not a rounding of it
            reached = tl == needed_l and tr == needed_r
            self.braking, self.target = False, None
        else:
            tl, tr = min(max(left_torque, -limit), limit), min(max(right_torque, -limit), limit)
        if reached:
            self.wheel_velocities = target  # type: ignore[assignment]
        else:
            a, g = step.rate_from_rate, step.rate_from_torque
            self.wheel_velocities = (
                a[0] * vl + a[1] * vr + g[0] * tl + g[1] * tr,
                a[2] * vl + a[3] * vr + g[2] * tl + g[3] * tr,
            )
        p, q = step.angle_from_rate, step.angle_from_torque
        left_travel = p[0] * vl + p[1] * vr + q[0] * tl + q[1] * tr
        right_travel = p[2] * vl + p[3] * vr + q[2] * tl + q[3] * tr
        self.wheel_angles = (self.wheel_angles[0] + left_travel, self.wheel_angles[1] + right_travel)
        self.applied = (tl, tr)
        self.move(left_travel, right_travel)

    def move(self, left_travel: float, right_travel: float) -> None:
        """Roll the body by the wheels' turns (rad): an arc of constant curvature."""
        model = self.model
        rl, rr = model.left_radius * left_travel, model.right_radius * right_travel
        distance = (rl + rr) / 2.0
        turn = (rr - rl) / (2.0 * model.half_axle)
        half = turn / 2.0
        # the chord of the arc: distance · sin(half)/half, along the mean heading
        chord = distance * (1.0 - half * half / 6.0 if abs(half) < 1e-6 else math.sin(half) / half)
        heading = self.theta + half
        self.x += chord * math.cos(heading)
        self.y += chord * math.sin(heading)
        self.theta += turn

    @property
    def linear_velocity(self) -> tuple[float, float, float]:
        """m/s of the axle centre, world frame."""
        speed, _ = self.model.body_velocity(*self.wheel_velocities)
        return speed * math.cos(self.theta), speed * math.sin(self.theta), 0.0

    @property
    def angular_velocity(self) -> tuple[float, float, float]:
        """rad/s, world frame (about z only: the body stays level)."""
        _, turn = self.model.body_velocity(*self.wheel_velocities)
        return 0.0, 0.0, turn
