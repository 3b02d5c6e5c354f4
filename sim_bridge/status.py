"""What the sim bridge reports: the world's part of every robot's ``sim/status`` (docs/sim.md), each
robot's planar pose and late fraction, and the summary line a run ends with. Pure: no zenoh."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from msgspec import UNSET

from schemas.messages import NANOSECONDS_PER_SECOND, LaserScan
from schemas.status import NearestHit, PlanarPose, SimParameters, SimWorldStatus
from services.config import SimConfig
from sim_bridge.progress import RunProgress

if TYPE_CHECKING:
    from sim_bridge.engine import Engine


def planar_pose(body_pose: Sequence[float]) -> PlanarPose:
    """x, y and heading of ``sim/body_pose``'s axle centre (x, y, z, rotation row-major)."""
    x, y, _z, r00, _r01, _r02, r10 = body_pose[:7]
    return PlanarPose(x, y, math.atan2(r10, r00))


def nearest_hit(scan: LaserScan) -> NearestHit | None:
    """The nearest thing ``scan``'s rays hit: its name (when the scan names it) and range; None
    when they hit nothing."""
    best: tuple[float, int] | None = None
    for ray, reading in enumerate(scan.ranges):
        if reading is not None and (best is None or reading < best[0]):
            best = (reading, ray)
    if best is None:
        return None
    reading, ray = best
    body = scan.bodies[scan.hits[ray]] if scan.hits else None
    return NearestHit(body, reading, scan.angle_min + ray * scan.angle_increment)


def robot_summary(counters: dict[str, int], pose: PlanarPose) -> str:
    listed = ", ".join(f"{name} {count}" for name, count in counters.items())
    return f"{listed}; pose x {pose.x:.4f} m, y {pose.y:.4f} m, theta {pose.theta:.4f} rad"


def late_fraction(counters: dict[str, int], steps: int, lockstep: bool) -> float:
    """Steps that came late: that waited past ``sim.lockstep_timeout`` (lockstep, ``long_waits``),
    whose torque came after the step (realtime)."""
    late = counters["long_waits" if lockstep else "realtime_late_steps"]
    return late / steps if steps else 0.0


@dataclass(kw_only=True)
class RunStatus:
    """The run as a whole: when its steps began and ended, how fast they went, what it simulates."""

    sim: Engine
    parameters: SimConfig
    progress: RunProgress
    world_file: Path
    duration: float | None
    fleet: list[str] | None
    """The robots' names in a fleet sim; None for one robot."""
    started_at: float | None = None
    stopped_at: float | None = None

    def elapsed(self) -> float:
        if self.started_at is None:
            return 0.0
        return (self.stopped_at if self.stopped_at is not None else time.monotonic()) - self.started_at

    def steps_per_second(self) -> float:
        elapsed = self.elapsed()
        return self.sim.step_index / elapsed if elapsed > 0.0 else 0.0

    def summary(self, robots: Sequence[str]) -> str:
        """The run's line: steps, times, and each robot's summary (:func:`robot_summary`)."""
        sim = self.sim
        head = (
            f"{sim.step_index} steps, {sim.time_ns / NANOSECONDS_PER_SECOND:.3f} s simulated "
            f"in {self.elapsed():.3f} s ({self.steps_per_second():.0f} steps/s)"
        )
        if self.fleet is None:
            return f"{head}; {robots[0]}"
        return head + "".join(f"; {name}: {robot}" for name, robot in zip(self.fleet, robots, strict=True))

    def world_status(self, finished: bool) -> SimWorldStatus:
        """The part of every robot's ``sim/status`` that is the world's."""
        sim, parameters = self.sim, self.parameters
        simulated = sim.time_ns / NANOSECONDS_PER_SECOND
        elapsed = self.elapsed()
        return SimWorldStatus(
            state="finished" if finished else ("running" if self.progress.started else "starting"),
            engine=parameters.engine,
            mode=parameters.mode,
            world=str(self.world_file),
            sim_time_s=simulated,
            steps=sim.step_index,
            steps_per_second=self.steps_per_second(),
            realtime_factor_achieved=simulated / elapsed if elapsed > 0.0 else 0.0,
            parameters=SimParameters(
                step=parameters.step,
                observe_every=parameters.observe_every,
                duration=self.duration,
                lockstep_timeout=parameters.lockstep_timeout,
                realtime_factor=parameters.realtime_factor,
                torque_max_age=parameters.torque_max_age,
                brake_after=parameters.brake_after,
                max_wheel_torque=parameters.max_wheel_torque,
            ),
            fleet=UNSET if self.fleet is None else list(self.fleet),
        )
