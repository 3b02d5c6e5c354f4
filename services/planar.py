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


def compose(pose: Pose, motion: Pose) -> Pose:
    """``pose * motion``: ``motion`` (given in ``pose``'s frame) in the frame ``pose`` is given in."""
    cos, sin = math.cos(pose.theta), math.sin(pose.theta)
    return Pose(
        pose.x + cos * motion.x - sin * motion.y,
        pose.y + sin * motion.x + cos * motion.y,
        wrap_angle(pose.theta + motion.theta),
    )


def inverse(pose: Pose) -> Pose:
    """The pose whose composition with ``pose`` is the identity."""
    cos, sin = math.cos(pose.theta), math.sin(pose.theta)
    return Pose(-(cos * pose.x + sin * pose.y), sin * pose.x - cos * pose.y, wrap_angle(-pose.theta))


def relative_motion(start: Pose, end: Pose) -> Pose:
    """``end`` seen from ``start``: the motion between two poses in ``start``'s frame."""
    cos, sin = math.cos(start.theta), math.sin(start.theta)
    dx, dy = end.x - start.x, end.y - start.y
    return Pose(cos * dx + sin * dy, -sin * dx + cos * dy, wrap_angle(end.theta - start.theta))


def check_coordinates(x: float, y: float, max_coordinate: float) -> None:
    """Raise BadInput unless both coordinates are finite and within ±``max_coordinate`` (m): a pose
    at 1e308 m is well-formed but no robot is there (``input.max_coordinate``)."""
    if not (math.isfinite(x) and math.isfinite(y)):
        raise BadInput(f"position ({x}, {y}) is not finite")
    if not (abs(x) <= max_coordinate and abs(y) <= max_coordinate):
        raise BadInput(f"position ({x:g}, {y:g}) m is beyond ±{max_coordinate:g} m (input.max_coordinate)")
