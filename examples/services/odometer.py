"""An odometer: a service that watches (docs/extending.md).

It reads the robot's pose (``odometry/pose``), adds up the distance travelled, and publishes it
with the speed on ``invent/<robot>/odometer/distance`` at 10 Hz of simulation time, taking part in
lockstep: in a lockstep run the simulator waits for each of its outputs, so they are the same,
bit for bit, in every run. Its status says the distance, the speed and the poses taken.

Run it beside the loop::

    invent up --with examples/services/odometer.py:Odometer

or alone, beside a running loop (it connects as any service does)::

    invent service examples/services/odometer.py:Odometer --connect tcp/127.0.0.1:7447

and watch it: ``invent echo 'invent/rh0/odometer/**'``, ``invent status``.
"""

from __future__ import annotations

import math
from typing import Any

import msgspec

from schemas.messages import TimedPosition
from services.extension.api import BadInput, Context, Lockstep, Time, UserService


class Travelled(msgspec.Struct, frozen=True):
    """``odometer/distance``: stamped with the simulation time of the pose it is made of."""

    tm: Time
    distance: float
    """Metres travelled since the service started (the sum of the steps between poses)."""
    speed: float
    """m/s over the last tick (distance between ticks / simulation time between them)."""


MAX_STEP_M = 1.0
"""A step between two poses longer than this is not travel (a reset pose): bad input."""


class Odometer(UserService):
    name = "odometer"
    reads = ("odometry/pose",)
    lockstep = Lockstep(output="distance", rate_hz=10.0)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        self.distance = 0.0
        self.speed = 0.0
        self.poses = 0
        self.last: TimedPosition | None = None
        self.tick_distance = 0.0
        self.tick_ns: int | None = None
        self.out = ctx.output("distance", Travelled)
        ctx.subscribe(ctx.keys.odometry_pose, TimedPosition, self.on_pose)

    def on_pose(self, pose: TimedPosition) -> None:
        last = self.last
        if last is not None:
            if pose.tm.to_nanoseconds() < last.tm.to_nanoseconds():
                self.last = None  # a new simulator: its clock starts again
            else:
                step = math.hypot(pose.x - last.x, pose.y - last.y)
                if step > MAX_STEP_M:
                    self.last = pose
                    raise BadInput(f"a step of {step:.2f} m between two poses")
                self.distance += step
        self.last = pose
        self.poses += 1
        if self.ctx.tick(pose.tm):
            now_ns = pose.tm.to_nanoseconds()
            if self.tick_ns is not None and now_ns > self.tick_ns:
                self.speed = (self.distance - self.tick_distance) * 1e9 / (now_ns - self.tick_ns)
            self.tick_ns, self.tick_distance = now_ns, self.distance
            self.out.put(Travelled(tm=pose.tm, distance=self.distance, speed=self.speed))

    def status(self) -> dict[str, Any]:
        return {"distance_m": round(self.distance, 6), "speed_m_s": round(self.speed, 6), "poses": self.poses}
