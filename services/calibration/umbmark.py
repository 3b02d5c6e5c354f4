"""UMBmark: a differential-drive robot's systematic odometry errors from where it really stops
after driving a square on odometry alone, clockwise and counter-clockwise, and the corrections
(Borenstein and Feng, "Measurement and correction of systematic odometry errors in mobile robots",
IEEE Transactions on Robotics and Automation 12(6), 1996). Pure: no zenoh.

The frame (docs/odometry.md, "Calibration: UMBmark"): the robot starts at the origin facing +x,
y to its left, angles counter-clockwise. Each run drives a square of side L: along +x first, then
turning on the spot 90° left at each corner (``ccw``) or right (``cw``), back to the start
(:func:`square`). A run's return position error is ε = (x, y) where the robot really stopped
minus where its odometry says it stopped. With the centres of gravity of the n errors of each
direction (x_cw, y_cw) and (x_ccw, y_ccw), the paper's first-order formulas, whose signs hold in
this frame (checked by driving an ideal robot with known errors round the square, and the
simulated one with errors injected: tests/test_umbmark.py, tests/test_calibrate.py):

    α  = (x_cw + x_ccw)/(−4L)        each 90° turn short by α (rad): the wheelbase error
    β  = (x_cw − x_ccw)/(−4L)        each leg curved left by β (rad): the wheel diameters' error
    R  = (L/2)/sin(β/2)              the radius of that curve
    Ed = D_R/D_L = (R + b/2)/(R − b/2) = (L + b·sin(β/2))/(L − b·sin(β/2))
    Eb = b_actual/b_nominal = (π/2)/(π/2 − α)
    E_max,syst = max(|cg_cw|, |cg_ccw|)

b is the wheelbase the odometry used (``length_of_axle``·``axle_scale``). The corrections keep
the mean of the two radii: UMBmark sees the ratio of the diameters, never their common scale
(a robot whose wheels are both 1 % large drives a square 1 % large and still returns to its
start). Ed > 1 means the right wheel is the larger, so the odometry's right radius must grow:
``right_radius_scale`` ×= 2/(1/Ed + 1), ``left_radius_scale`` ×= 2/(Ed + 1), ``axle_scale`` ×= Eb.
The paper writes the two wheel factors the other way round (c_L = 2/(1/Ed + 1), c_R = 2/(Ed + 1));
with Ed = D_R/D_L as computed in this frame, that assignment about doubles the curve instead of
removing it (the tests drive both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from services.config import OdometryConfig

Point = tuple[float, float]

DEFAULT_SIDE = 4.0
"""m: the paper's square."""
DEFAULT_RUNS = 5
"""Runs in each direction: the paper's."""
CONVERGED = 5e-4
"""A correction whose multipliers all lie within this of 1 is not worth another pass: two to
four times the simulator's own floor (corrections of 1.4e-4 to 2.4e-4 with no error injected,
docs/odometry.md)."""


class Direction(StrEnum):
    CW = "cw"
    """Clockwise: turning right at every corner."""
    CCW = "ccw"
    """Counter-clockwise: turning left at every corner."""

    @property
    def turn(self) -> float:
        """+1 for a left turn, −1 for a right one: the sign of the square's y."""
        return 1.0 if self is Direction.CCW else -1.0


def square(side: float, direction: Direction) -> list[Point]:
    """The square's corners after the start, the last one the start itself: from the origin along
    +x, then ``direction`` at each corner."""
    y = side * direction.turn
    return [(side, 0.0), (side, y), (0.0, y), (0.0, 0.0)]


@dataclass(frozen=True)
class Calibration:
    """The three calibration multipliers of ``[odometry]`` (1: none)."""

    left_radius_scale: float = 1.0
    right_radius_scale: float = 1.0
    axle_scale: float = 1.0

    @classmethod
    def of(cls, odometry: OdometryConfig) -> Calibration:
        return cls(odometry.left_radius_scale, odometry.right_radius_scale, odometry.axle_scale)

    def then(self, correction: Calibration) -> Calibration:
        """This calibration corrected by ``correction`` (each multiplier times the correction's)."""
        return Calibration(
            self.left_radius_scale * correction.left_radius_scale,
            self.right_radius_scale * correction.right_radius_scale,
            self.axle_scale * correction.axle_scale,
        )

    def overrides(self) -> dict[str, float]:
        """The config keys and values of this calibration, as ``--set`` takes them."""
        return {f"odometry.{name}": value for name, value in self.as_dict().items()}

    def as_dict(self) -> dict[str, float]:
        return {
            "left_radius_scale": self.left_radius_scale,
            "right_radius_scale": self.right_radius_scale,
            "axle_scale": self.axle_scale,
        }

    def deviation(self) -> float:
        """The largest |multiplier − 1|."""
        return max(abs(value - 1.0) for value in self.as_dict().values())


def correction(ed: float, eb: float) -> Calibration:
    """The multipliers that correct a robot whose diameter ratio D_R/D_L is ``ed`` times and whose
    wheelbase is ``eb`` times what the odometry takes: the ratio becomes ``ed``'s, the mean radius stays."""
    return Calibration(left_radius_scale=2.0 / (ed + 1.0), right_radius_scale=2.0 / (1.0 / ed + 1.0), axle_scale=eb)


def centre_of_gravity(points: Sequence[Point]) -> Point:
    if not points:
        raise ValueError("no return positions")
    return sum(x for x, _ in points) / len(points), sum(y for _, y in points) / len(points)


def return_error(truth: Point, odometry: Point) -> Point:
    """ε of one run: where the robot really stopped minus where its odometry says it stopped."""
    return truth[0] - odometry[0], truth[1] - odometry[1]


@dataclass(frozen=True)
class Umbmark:
    """The evaluation of one benchmark: n runs each way round a square of side ``side``."""

    side: float
    wheelbase: float
    """b, m: the wheelbase the odometry used."""
    cw: tuple[Point, ...]
    """The clockwise runs' return position errors ε, m."""
    ccw: tuple[Point, ...]
    cg_cw: Point
    cg_ccw: Point
    alpha: float
    """rad: each turn short by this."""
    beta: float
    """rad: each leg curved left by this."""
    radius: float
    """m: the curve's radius R (negative: curved right; infinite: straight)."""
    ed: float
    """D_R/D_L, relative to the ratio the odometry used."""
    eb: float
    """The wheelbase, relative to the one the odometry used."""
    e_max_syst: float
    """m: the larger distance of the two centres of gravity from the start."""
    correction: Calibration
    """What to multiply the odometry's calibration with."""

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (an infinite radius is None)."""
        return {
            "side": self.side,
            "wheelbase": self.wheelbase,
            "return_errors": {"cw": [list(p) for p in self.cw], "ccw": [list(p) for p in self.ccw]},
            "centres_of_gravity": {"cw": list(self.cg_cw), "ccw": list(self.cg_ccw)},
            "alpha": self.alpha,
            "beta": self.beta,
            "radius": self.radius if math.isfinite(self.radius) else None,
            "ed": self.ed,
            "eb": self.eb,
            "e_max_syst": self.e_max_syst,
            "correction": self.correction.as_dict(),
        }


def evaluate(side: float, wheelbase: float, cw: Sequence[Point], ccw: Sequence[Point]) -> Umbmark:
    """UMBmark's evaluation of the return position errors ``cw`` and ``ccw`` (m) of a square of
    side ``side`` (m) driven by a robot whose odometry takes the wheelbase ``wheelbase`` (m).
    ValueError, saying why, for input the formulas cannot take."""
    if not (math.isfinite(side) and side > 0.0):
        raise ValueError(f"the square's side must be a positive length, got {side}")
    if not (math.isfinite(wheelbase) and wheelbase > 0.0):
        raise ValueError(f"the wheelbase must be a positive length, got {wheelbase}")
    for name, points in (("cw", cw), ("ccw", ccw)):
        if not points:
            raise ValueError(f"no {name} return positions: UMBmark needs runs in both directions")
        if not all(math.isfinite(value) for point in points for value in point):
            raise ValueError(f"a {name} return position is not finite")
    cg_cw, cg_ccw = centre_of_gravity(cw), centre_of_gravity(ccw)
    alpha = (cg_cw[0] + cg_ccw[0]) / (-4.0 * side)
    beta = (cg_cw[0] - cg_ccw[0]) / (-4.0 * side)
    if abs(alpha) >= math.pi / 2.0:
        raise ValueError(
            f"the return positions give a turn error α = {alpha:.3g} rad, beyond what a 90° turn can miss by: "
            "are they in metres, and the clockwise and counter-clockwise runs the right way round?"
        )
    half_beta_sine = math.sin(beta / 2.0)
    if wheelbase * abs(half_beta_sine) >= side:
        raise ValueError(
            f"the return positions give a curve of radius {abs(side / 2.0 / half_beta_sine):.3g} m on each leg, "
            f"tighter than half the wheelbase ({wheelbase / 2.0:g} m): are they in metres?"
        )
    ed = (side + wheelbase * half_beta_sine) / (side - wheelbase * half_beta_sine)
    eb = (math.pi / 2.0) / (math.pi / 2.0 - alpha)
    return Umbmark(
        side=side,
        wheelbase=wheelbase,
        cw=tuple((float(x), float(y)) for x, y in cw),
        ccw=tuple((float(x), float(y)) for x, y in ccw),
        cg_cw=cg_cw,
        cg_ccw=cg_ccw,
        alpha=alpha,
        beta=beta,
        radius=side / 2.0 / half_beta_sine if half_beta_sine else math.inf,
        ed=ed,
        eb=eb,
        e_max_syst=max(math.hypot(*cg_cw), math.hypot(*cg_ccw)),
        correction=correction(ed, eb),
    )
