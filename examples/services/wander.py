"""A wanderer: a service that drives (docs/extending.md, A service that drives).

It reads the lidar (``sim/scan``) and drives the robot in the built-in drive's place: straight on
while the way ahead is clear, steering away from the nearer side, and turning in place towards the
more open side when something is ahead, until the way is clear again. One command per scan, stamped
with the scan's time, so that a lockstep run is the same, bit for bit, every time. It never ends by
itself: ``invent up`` runs it until Ctrl-C, or until it gives up as the drive does (the motor
stopped by a bump, or held by its collision monitor, for ``drive.give_up_after_stop``).

Run it in the drive's place::

    invent up --with examples/services/wander.py:Wander --set sim.world=room

The deciding is plain Python (:class:`Wanderer`, no zenoh): test it with scans of your own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from schemas.messages import LaserScan
from services.extension.api import Context, Drives, UserService

SCAN_RATE_HZ = 10.0
"""The lidar's default rate (``lidar.rate``): one command per scan."""
SPEED = 0.25
"""m/s on a clear way."""
TURN_RATE = 0.8
"""rad/s turning in place."""
STEER_GAIN = 0.6
"""rad/s per metre of difference between the room on the left and on the right."""
CORRIDOR_MARGIN = 0.15
"""Added to the body's radius on each side: what is within that of the robot's line counts as ahead."""
TURN_BELOW = 1.2
"""Metres of clear way ahead (from the robot's centre) under which it stops and turns."""
CLEAR_ABOVE = 1.8
"""Metres of clear way ahead over which a turn ends."""


@dataclass(frozen=True)
class Room:
    """What a scan says around the robot: the clear way ahead along its body's corridor, and the
    nearest return on each side (metres; the scan's ``range_max`` where there is nothing)."""

    ahead: float
    left: float
    right: float


def room_around(scan: LaserScan, half_width: float) -> Room:
    """The :class:`Room` of ``scan`` for a body ``half_width`` wide on each side of its line."""
    ahead = left = right = scan.range_max
    for index, reading in enumerate(scan.ranges):
        if reading is None:
            continue
        angle = math.remainder(scan.angle_min + index * scan.angle_increment, math.tau)
        forward, lateral = reading * math.cos(angle), reading * math.sin(angle)
        if forward > 0.0 and abs(lateral) < half_width:
            ahead = min(ahead, forward)
        elif math.radians(20.0) <= angle <= math.radians(110.0):
            left = min(left, reading)
        elif -math.radians(110.0) <= angle <= -math.radians(20.0):
            right = min(right, reading)
    return Room(ahead, left, right)


class Wanderer:
    """The deciding, pure: the velocity for each :class:`Room`, turning until the way is clear."""

    def __init__(self) -> None:
        self.turning = 0.0
        """The turn's direction (+1 left, -1 right) while it turns in place; 0 while it drives on."""
        self.turns = 0

    def command(self, room: Room) -> tuple[float, float]:
        """(vx, w) for ``room``."""
        if self.turning and room.ahead > CLEAR_ABOVE:
            self.turning = 0.0
        elif not self.turning and room.ahead < TURN_BELOW:
            self.turning = 1.0 if room.left >= room.right else -1.0
            self.turns += 1
        if self.turning:
            return 0.0, self.turning * TURN_RATE
        steer = STEER_GAIN * (min(room.left, 2.0) - min(room.right, 2.0))
        return SPEED, max(-TURN_RATE, min(TURN_RATE, steer))


class Wander(UserService):
    name = "wander"
    reads = ("sim/scan",)
    drives = Drives(rate_hz=SCAN_RATE_HZ)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        lidar = ctx.config.lidar
        if not lidar.enabled or lidar.rate != SCAN_RATE_HZ:
            raise ValueError(f"wander drives on each scan: it needs the lidar at {SCAN_RATE_HZ:g} Hz (lidar.rate)")
        self.half_width = ctx.config.robot.radius_of_body_area + CORRIDOR_MARGIN
        self.wanderer = Wanderer()
        self.scans = 0
        self.nearest_ahead: float | None = None
        ctx.subscribe(ctx.keys.sim_scan, LaserScan, self.on_scan)

    def on_scan(self, scan: LaserScan) -> None:
        self.scans += 1
        room = room_around(scan, self.half_width)
        self.nearest_ahead = room.ahead
        vx, w = self.wanderer.command(room)
        self.ctx.drive(scan.tm, vx, w)

    def status(self) -> dict[str, Any]:
        return {"scans": self.scans, "turns": self.wanderer.turns, "ahead_m": self.nearest_ahead}
