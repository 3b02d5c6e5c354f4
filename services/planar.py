"""Planar poses and angles shared by the services' cores (pure, no zenoh)."""

from __future__ import annotations

import math
from typing import NamedTuple

from schemas.codec import BadInput

_TAU = 2.0 * math.pi


class Pose(NamedTuple):
    """A planar pose: position in m, heading in rad (counter-clockwise from +x)."""

    x: float
    y: float
    theta: float


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped into (−π, π] (``math.remainder`` is exact, so |result| <= π)."""
    wrapped = math.remainder(angle, _TAU)
    return math.pi if wrapped == -math.pi else wrapped


def check_coordinates(x: float, y: float, max_coordinate: float) -> None:
    """Raise BadInput unless both coordinates are finite and within ±``max_coordinate`` (m): a pose
    at 1e308 m is well-formed but no robot is there (``input.max_coordinate``)."""
    if not (math.isfinite(x) and math.isfinite(y)):
        raise BadInput(f"position ({x}, {y}) is not finite")
    if not (abs(x) <= max_coordinate and abs(y) <= max_coordinate):
        raise BadInput(f"position ({x:g}, {y:g}) m is beyond ±{max_coordinate:g} m (input.max_coordinate)")
