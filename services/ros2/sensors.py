"""The robot's sensors as ROS 2 has them (pure, no zenoh): ``sim/scan`` as sensor_msgs/LaserScan,
``sim/imu`` as sensor_msgs/Imu, and their frames, fixed on the base as TurtleBot3's ``base_scan``
and ``imu_link`` are (``ros2.scan_frame``, ``ros2.imu_frame``, at the ``[lidar]`` and ``[imu]``
mounts): links of the URDF and transforms of ``/tf_static``.

A LaserScan: ``null`` ranges (nothing within ``range_max``) are +inf (REP 117), the ranges float32,
no intensities, ``angle_max`` the last ray's angle, ``time_increment`` 0 (the simulator casts every
ray at the scan's instant), ``scan_time`` 1/``lidar.rate``. An Imu: the covariances of angular
velocity and linear acceleration are diagonal, the variance of each axis the square of
``imu.gyro_noise`` and ``imu.accel_noise`` (0 for a noiseless IMU, which sensor_msgs reads as "not
known"); the orientation's is ``orientation_covariance[0] = -1`` when the sample has none (REP 145:
no orientation), else :data:`ORIENTATION_VARIANCE` on its diagonal.

Bad input (BadInput, nothing published): a sample stamped at or before the last one of its sensor,
or more than ``input.stamp_horizon`` ahead of the bridge's clock; a scan without rays, or with a
number ROS's float32 cannot hold; a stamp beyond ROS's int32 seconds. The runtime's typed decode
has already refused what is malformed or not finite (schemas/messages.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, ImuSample, LaserScan
from services.config import Config
from services.ros2 import core, interfaces

ORIENTATION_VARIANCE = 1e-6
"""rad², each axis of an Imu's orientation covariance when the sample has an orientation (the
simulator's ground truth, or a sensor's estimate)."""
NO_ORIENTATION = -1.0
"""``orientation_covariance[0]`` of an Imu without orientation (REP 145)."""
FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_ROS_SECONDS = 2**31 - 1
"""builtin_interfaces/Time's ``sec`` is an int32."""


@dataclass(frozen=True)
class SensorFrame:
    """A sensor's frame, fixed on the base frame at (x, y, z), turned by ``yaw`` about z."""

    frame: str
    x: float
    y: float
    z: float
    yaw: float = 0.0

    @property
    def joint(self) -> str:
        """Its fixed joint in the URDF (``<frame>_joint``, as the casters')."""
        return f"{self.frame}_joint"


def sensor_frames(config: Config) -> tuple[SensorFrame, ...]:
    """The frames of the sensors the robot has (``lidar.enabled``, ``imu.enabled``)."""
    lidar, imu, settings = config.lidar, config.imu, config.ros2
    frames = []
    if lidar.enabled:
        frames.append(SensorFrame(settings.scan_frame, lidar.x, lidar.y, lidar.z, lidar.yaw))
    if imu.enabled:
        frames.append(SensorFrame(settings.imu_frame, imu.x, imu.y, imu.z))
    return tuple(frames)


def static_transforms(stamp_ns: int, base_frame: str, frames: tuple[SensorFrame, ...], prefix: str = "") -> list[Any]:
    """``base_link -> <sensor frame>`` for ``/tf_static`` (each frame's name after ``prefix``)."""
    return [
        core.transform(stamp_ns, base_frame, prefix + f.frame, f.x, f.y, f.z, core.yaw_rotation(f.yaw)) for f in frames
    ]


class SensorStamps:
    """Each sensor's last stamp taken: a sample of a sensor is newer than the one before (the
    drive's map, costmap and plan are kept in order likewise, services/ros2/outputs.py)."""

    def __init__(self, horizon_ns: int) -> None:
        self.horizon_ns = horizon_ns
        self._last_ns: dict[str, int] = {}

    def check(self, sensor: str, stamp_ns: int, clock_ns: int | None, *, repeat: bool = False) -> None:
        """BadInput when ``stamp_ns`` is not after the sensor's last (before it, with ``repeat``: a
        latched message sent again keeps its stamp), runs more than the horizon ahead of the
        bridge's clock (``clock_ns``, None before its first sample), or is beyond ROS's time; else it
        is the sensor's last."""
        last_ns = self._last_ns.get(sensor)
        if last_ns is not None and (stamp_ns < last_ns if repeat else stamp_ns <= last_ns):
            relation = "before" if repeat else "not after"
            raise BadInput(f"stamp {_seconds(stamp_ns)} s is {relation} the last {sensor}'s, {_seconds(last_ns)} s")
        if clock_ns is not None and stamp_ns - clock_ns > self.horizon_ns:
            raise BadInput(
                f"stamp {_seconds(stamp_ns)} s is more than input.stamp_horizon ahead of the clock, {_seconds(clock_ns)} s"
            )
        if stamp_ns // NANOSECONDS_PER_SECOND > MAX_ROS_SECONDS:
            raise BadInput(f"stamp {_seconds(stamp_ns)} s is beyond ROS's time (int32 seconds)")
        self._last_ns[sensor] = stamp_ns

    def restart(self) -> None:
        """A new simulator: its stamps start again."""
        self._last_ns.clear()


def _seconds(stamp_ns: int) -> str:
    return f"{stamp_ns / NANOSECONDS_PER_SECOND:.3f}"


def _float32(name: str, values: list[float]) -> np.ndarray:
    """``values`` as float32; BadInput naming ``name`` for a finite one beyond float32's range."""
    if any(math.isfinite(value) and abs(value) > FLOAT32_MAX for value in values):
        raise BadInput(f"{name}: a number beyond float32's range")
    return np.array(values, dtype=np.float32)


def laser_scan(scan: LaserScan, frame: str, rate_hz: float) -> Any:
    """sensor_msgs/LaserScan of ``scan`` in ``frame`` (the lidar's), ``scan_time`` 1/``rate_hz``."""
    count = len(scan.ranges)
    if count == 0:
        raise BadInput("a scan without rays")
    angle_max = scan.angle_min + (count - 1) * scan.angle_increment
    limits = _float32("angles and range limits", [scan.angle_min, angle_max, scan.angle_increment])
    range_limits = _float32("angles and range limits", [scan.range_min, scan.range_max])
    return interfaces.message_class(interfaces.LASER_SCAN)(
        header=core.header(scan.tm.to_nanoseconds(), frame),
        angle_min=float(limits[0]),
        angle_max=float(limits[1]),
        angle_increment=float(limits[2]),
        time_increment=0.0,
        scan_time=float(np.float32(1.0 / rate_hz)),
        range_min=float(range_limits[0]),
        range_max=float(range_limits[1]),
        ranges=_float32("ranges", scan.ranges_or_inf()),
        intensities=np.array((), dtype=np.float32),
    )


def _diagonal(variances: tuple[float, float, float]) -> np.ndarray:
    """A row-major 3x3 ``float64[9]`` with ``variances`` on its diagonal."""
    return np.diag(np.array(variances, dtype=np.float64)).reshape(9)


def orientation_covariance(sample: ImuSample) -> np.ndarray:
    if sample.orientation_source == "none":
        covariance = np.zeros(9, dtype=np.float64)
        covariance[0] = NO_ORIENTATION
        return covariance
    return _diagonal((ORIENTATION_VARIANCE,) * 3)


def imu(sample: ImuSample, frame: str, gyro_noise: float, accel_noise: float) -> Any:
    """sensor_msgs/Imu of ``sample`` in ``frame`` (the IMU's), the covariances from the noise's
    standard deviations (rad/s, m/s²)."""
    x, y, z, w = sample.orientation
    return interfaces.message_class(interfaces.IMU)(
        header=core.header(sample.tm.to_nanoseconds(), frame),
        orientation=core.quaternion(x, y, z, w),
        orientation_covariance=orientation_covariance(sample),
        angular_velocity=core.vector(*sample.angular_velocity),
        angular_velocity_covariance=_diagonal((gyro_noise**2,) * 3),
        linear_acceleration=core.vector(*sample.linear_acceleration),
        linear_acceleration_covariance=_diagonal((accel_noise**2,) * 3),
    )
