"""The simulator's body pose as the motor reports it: ``sim/body_pose`` (the model's base, a
position and a rotation matrix) turned into [X, Y, Z, theta] of the axle centre, the point the
odometry integrates. Pure: the motor's ``motor/sim_pose/*`` and the run report's ground truth both use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from schemas.codec import BadInput
from schemas.topics import BODY_POSE_LENGTH
from services.config import MotorConfig
from services.planar import wrap_angle


class SimPoseConverter:
    """``sim/body_pose`` (x, y, z, 3x3 rotation row-major) -> [X, Y, Z, theta] of the axle centre.

    docs/protocol.md section 4 with atan2 (correction 2): theta_o = atan2(-A12, A11); the offset
    (offset_x, offset_y) is the axle centre in the model frame, turned by theta_o.
    """

    def __init__(self, offset_x: float = 0.0, offset_y: float = 0.0, offset_angle: float = 0.0) -> None:
        self.offset_x, self.offset_y, self.offset_angle = offset_x, offset_y, offset_angle
        self._length = math.hypot(offset_x, offset_y)
        self._direction = math.atan2(offset_y, offset_x)

    @classmethod
    def from_config(cls, motor: MotorConfig) -> SimPoseConverter:
        return cls(motor.simulated_offset_x, motor.simulated_offset_y, motor.simulated_offset_angle)

    def __call__(self, data: Sequence[float]) -> list[float]:
        if len(data) != BODY_POSE_LENGTH:
            raise BadInput(f"body pose has {len(data)} values, expected {BODY_POSE_LENGTH}")
        theta_o = math.atan2(-data[4], data[3])
        bearing = theta_o + self._direction
        return [
            data[0] + self._length * math.cos(bearing),
            data[1] + self._length * math.sin(bearing),
            data[2],
            wrap_angle(theta_o + self.offset_angle),
        ]
