"""Planar poses and angles shared by the services' cores (pure, no zenoh)."""

from __future__ import annotations

import math
from typing import NamedTuple

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
