"""The simulated sensors' own arithmetic (docs/protocol.md section 6.6): where a robot's lidar rays
go and what their hits read, and what its IMU measures. Pure: numpy, no PyBullet (the simulator
casts the rays and reads the velocities, :mod:`sim_bridge.simulator`), no zenoh.

Both are sampled on the simulation clock, on the grid of their rate
(:class:`~services.clock.sim_time.PeriodicSchedule`), so a lockstep run samples the same states
and, with the noise drawn from a seeded generator per robot, publishes the same numbers every run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from schemas.messages import NANOSECONDS_PER_SECOND, NO_HIT, ImuSample, LaserScan, Quaternion, Time
from services.clock.sim_time import PeriodicSchedule
from services.config import ConfigError, ImuConfig, LidarConfig

GRAVITY = 9.81
"""m/s^2, along -z (the simulator's)."""
FOOTPRINT_CLEARANCE = 0.001
"""m beyond the robot's own footprint where its rays start: a ray never sees its own robot."""
Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
RayHit = tuple[int, int, float, Sequence[float], Sequence[float]]
"""One ray's result as PyBullet's ``rayTestBatch`` gives it: body id (-1: none), link, hit
fraction along the ray, hit position, hit normal."""


def footprint_exit(mount: tuple[float, float], direction: tuple[float, float], reach: float) -> float:
    """How far along a ray from ``mount`` (base frame, m) in the unit ``direction`` the ray leaves
    the circle of radius ``reach`` about the base's origin (the robot's footprint); 0 when it is
    not in it ahead."""
    along = mount[0] * direction[0] + mount[1] * direction[1]
    discriminant = along * along - (mount[0] ** 2 + mount[1] ** 2 - reach * reach)
    if discriminant <= 0.0:
        return 0.0
    return max(0.0, -along + math.sqrt(discriminant))


class Lidar:
    """One robot's 2D lidar: its rays in the base frame, each from where it leaves the robot's
    footprint (radius ``reach``) to ``range_max``, and the scan their hits make."""

    def __init__(self, lidar: LidarConfig, reach: float, stream: int) -> None:
        self.config = lidar
        count = lidar.rays
        headings = lidar.yaw + lidar.angle_min + lidar.angle_increment * np.arange(count)
        directions = np.stack([np.cos(headings), np.sin(headings), np.zeros(count)], axis=1)
        mount = np.array([lidar.x, lidar.y, lidar.z])
        starts = np.array(
            [
                max(lidar.range_min, footprint_exit((lidar.x, lidar.y), (dx, dy), reach) + FOOTPRINT_CLEARANCE)
                for dx, dy, _ in directions
            ]
        )
        if float(starts.max()) >= lidar.range_max:
            raise ConfigError(
                f"`lidar.range_max`: {lidar.range_max} m ends inside the robot's own footprint "
                f"(its rays leave it {float(starts.max()):.3f} m from the lidar)"
            )
        self.starts = starts
        self.lengths = lidar.range_max - starts
        self.local_from = mount + starts[:, None] * directions
        self.local_to = mount + lidar.range_max * directions
        self.schedule = PeriodicSchedule(lidar.rate, 0)
        self._noise = lidar.noise
        self._rng = np.random.default_rng([lidar.seed, stream])

    def rays(self, position: Sequence[float], rotation: Array) -> tuple[Array, Array]:
        """Each ray's start and end in the world, for the base at ``position`` turned by ``rotation``."""
        origin = np.asarray(position)
        return origin + self.local_from @ rotation.T, origin + self.local_to @ rotation.T

    def scan(self, tm: Time, hits: Sequence[RayHit], names: Mapping[int, str]) -> LaserScan:
        """The scan of ``hits`` (one per ray, in ray order; PyBullet's): :meth:`scan_of` their
        bodies and fractions."""
        columns = tuple(zip(*hits, strict=True))
        return self.scan_of(tm, np.array(columns[0], dtype=np.int64), np.array(columns[2], dtype=np.float64), names)

    def scan_of(self, tm: Time, bodies: IntArray, fractions: Array, names: Mapping[int, str]) -> LaserScan:
        """The scan of each ray's first hit, in ray order: the body it hit (``NO_HIT``: none;
        ``names``: body id -> name) and how far along the ray (1.0: none). Its range from the
        lidar, with its noise."""
        lidar = self.config
        ranges = self.starts + fractions * self.lengths
        if self._noise > 0.0:
            # drawn for every ray, hit or not, so that each scan takes the same share of the stream
            ranges = np.clip(ranges + self._rng.normal(0.0, self._noise, ranges.size), lidar.range_min, lidar.range_max)
        readings: list[float | None] = ranges.tolist()
        for ray in np.flatnonzero(bodies == NO_HIT).tolist():
            readings[ray] = None
        # counted by body id + 1 (NO_HIT is -1); a body's rank among those seen is its index in
        # the scan's list, NO_HIT's slot always counted first so that it ranks -1
        present = np.bincount(bodies + 1, minlength=1) > 0
        present[0] = True
        index_of = np.cumsum(present) - 2
        return LaserScan(
            tm=tm,
            angle_min=lidar.angle_min,
            angle_increment=lidar.angle_increment,
            range_min=lidar.range_min,
            range_max=lidar.range_max,
            ranges=readings,
            bodies=[names.get(body, f"body {body}") for body in np.flatnonzero(present[1:]).tolist()],
            hits=index_of[bodies + 1].tolist(),
        )


class Imu:
    """One robot's IMU at ``mount`` on the base, the base's axes: the angular velocity and the
    specific force there (the mount point's acceleration, differenced over one sample period, less
    gravity), with bias and seeded noise, and the simulator's orientation. Plain floats, not numpy:
    at 100 Hz of 1 ms steps it runs every tenth step, and numpy's per-call cost would triple it."""

    def __init__(self, imu: ImuConfig, stream: int) -> None:
        self.config = imu
        self.mount = (imu.x, imu.y, imu.z)
        self.schedule = PeriodicSchedule(imu.rate, 0)
        self._rng = np.random.default_rng([imu.seed, stream])
        self._previous: tuple[int, float, float, float] | None = None
        """Stamp and world velocity of the mount point at the last sample."""

    def sample(
        self,
        tm: Time,
        orientation: Quaternion,
        rotation: Sequence[float],
        linear_velocity: Sequence[float],
        angular_velocity: Sequence[float],
    ) -> ImuSample:
        """What the IMU reads at ``tm`` for the base turned by ``rotation`` (3×3, row-major;
        ``orientation`` as a quaternion) moving at ``linear_velocity`` and ``angular_velocity``
        (world frame). The first sample takes the robot to be at rest."""
        imu = self.config
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation
        mx, my, mz = self.mount
        # the mount in world axes, and its velocity v + ω × r
        rx, ry, rz = r00 * mx + r01 * my + r02 * mz, r10 * mx + r11 * my + r12 * mz, r20 * mx + r21 * my + r22 * mz
        wx, wy, wz = angular_velocity
        vx, vy, vz = linear_velocity
        vx, vy, vz = vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx
        stamp_ns = tm.to_nanoseconds()
        previous, self._previous = self._previous, (stamp_ns, vx, vy, vz)
        if previous is None or stamp_ns <= previous[0]:
            ax = ay = az = 0.0
        else:
            rate = NANOSECONDS_PER_SECOND / (stamp_ns - previous[0])
            ax, ay, az = (vx - previous[1]) * rate, (vy - previous[2]) * rate, (vz - previous[3]) * rate
        az += GRAVITY
        # into the IMU's (the base's) axes: Rᵀ·v
        gyro = [
            r00 * wx + r10 * wy + r20 * wz + imu.gyro_bias[0],
            r01 * wx + r11 * wy + r21 * wz + imu.gyro_bias[1],
            r02 * wx + r12 * wy + r22 * wz + imu.gyro_bias[2],
        ]
        accel = [
            r00 * ax + r10 * ay + r20 * az + imu.accel_bias[0],
            r01 * ax + r11 * ay + r21 * az + imu.accel_bias[1],
            r02 * ax + r12 * ay + r22 * az + imu.accel_bias[2],
        ]
        if imu.gyro_noise > 0.0:
            gyro = [value + noise for value, noise in zip(gyro, self._rng.normal(0.0, imu.gyro_noise, 3).tolist())]
        if imu.accel_noise > 0.0:
            accel = [value + noise for value, noise in zip(accel, self._rng.normal(0.0, imu.accel_noise, 3).tolist())]
        return ImuSample(
            tm=tm,
            orientation=orientation,
            orientation_source="simulator",
            angular_velocity=(gyro[0], gyro[1], gyro[2]),
            linear_acceleration=(accel[0], accel[1], accel[2]),
        )
