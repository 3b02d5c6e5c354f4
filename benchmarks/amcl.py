"""The ``amcl`` section of ``make bench``: what the particle filter (services/localization/amcl.py) costs
per scan with the default ``[amcl]`` and lidar, on the synthetic room of tests/amcl_world.py (6 × 4 m,
5 cm cells), the robot driving its loop with wheels 1 % off.

- **Update**: :meth:`ParticleFilter.update` when it updates (motion, weighting, resampling, estimate),
  median and p95 over the updates of a drive, at the converged count (``min_particles``) and at
  ``max_particles`` (a fixed count: what the first updates after a seed or during a recovery cost);
  the scans are cast beforehand, not timed. With the position error (RMS) of the converged run.
- **Likelihood field**: building :class:`LikelihoodField` for a 400 × 400 map (20 × 20 m at 5 cm).

Each update is also given as a share of the lidar's period (0.1 s at 10 Hz).
"""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

import numpy as np

from services.config.amcl import AmclConfig
from services.config.sensors import LidarConfig
from services.localization.amcl import ParticleFilter
from services.localization.likelihood import LikelihoodField
from services.navigation.grid import FREE, OCCUPIED, Grid, GridGeometry
from services.planar import Pose
from tests import amcl_world as world


def updates(settings: AmclConfig, count: int) -> dict[str, Any]:
    """ms per update over ``count`` updates of a drive seeded at the truth; the position RMS."""
    lidar = world.LIDAR
    particle_filter = ParticleFilter(
        LikelihoodField(world.room_grid(), settings.likelihood_max_dist), settings, lidar, np.random.default_rng(0)
    )
    particle_filter.motion(Pose(0.0, 0.0, 0.0))
    particle_filter.seed(world.loop_pose(0.0))
    rng = np.random.default_rng(1)
    seconds = count * settings.update_min_d / 0.2 * 1.2 + 1.0  # 0.2 m/s: an update every 0.05 m or so
    path = [(true, odometry, world.cast(true, rng)) for true, odometry in world.drive(seconds)]
    times, errors, particles = [], [], []
    for true, odometry, ranges in path:
        particle_filter.motion(odometry)
        started = time.perf_counter()
        updated = particle_filter.update(
            ranges, lidar.angle_min, lidar.angle_increment, lidar.range_min, lidar.range_max
        )
        elapsed = time.perf_counter() - started
        if updated:
            times.append(elapsed * 1e3)
            estimate = particle_filter.estimate().pose
            errors.append(math.hypot(estimate.x - true.x, estimate.y - true.y))
            particles.append(particle_filter.xs.size)
        if len(times) == count:
            break
    steady = times[len(times) // 10 :]  # past the seed's first updates
    return {
        "updates": len(times),
        "ms": statistics.median(steady),
        "p95_ms": float(np.percentile(steady, 95)),
        "particles": statistics.median(particles),
        "rms_m": math.sqrt(statistics.fmean(error**2 for error in errors[len(errors) // 10 :])),
    }


def field_build_ms(repeats: int) -> float:
    """ms to build the likelihood field of a 400 × 400 map with walls and scattered boxes."""
    geometry = GridGeometry(0.05, 400, 400, -10.0, -10.0)
    cells = np.full(geometry.shape, FREE, dtype=np.int8)
    cells[:2, :] = cells[-2:, :] = cells[:, :2] = cells[:, -2:] = OCCUPIED
    rng = np.random.default_rng(0)
    for row, col in rng.integers(10, 380, size=(60, 2)):
        cells[row : row + 12, col : col + 8] = OCCUPIED
    grid = Grid(geometry, cells)
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        LikelihoodField(grid, AmclConfig().likelihood_max_dist)
        times.append((time.perf_counter() - started) * 1e3)
    return statistics.median(times)


def run(quick: bool) -> dict[str, Any]:
    """The section's figures (``quick``: a few updates)."""
    period_ms = 1e3 / LidarConfig().rate
    count = 20 if quick else 200
    default = AmclConfig()
    results: dict[str, Any] = {
        "lidar_period_ms": period_ms,
        "converged": updates(default, count),
        "max_particles": updates(AmclConfig(min_particles=default.max_particles), count),
        "field_build_ms": field_build_ms(2 if quick else 10),
    }
    for name in ("converged", "max_particles"):
        entry = results[name]
        entry["share"] = entry["ms"] / period_ms
        entry["p95_share"] = entry["p95_ms"] / period_ms
    return results


if __name__ == "__main__":
    print(run(quick=False))
