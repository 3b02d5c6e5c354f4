"""Records one run of the loop for the report, from zenoh, without slowing it down.

The samples wait in zenoh FIFO channels, where no Python runs per sample (a Python callback
per sample would compete for the GIL with the loop itself, which in ``invent up --composed``
runs in this same process: benchmarks/README.md); ``up`` collects their raw payloads with
:meth:`Recorder.collect` between its looks at the run, and decoding happens once, after the
run, in :meth:`Recorder.recording`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from schemas.codec import BadInput, decode
from schemas.keys import Keys
from schemas.messages import Time, TimedDoubleSeq, TimedPosition, TimedVelocity
from services.config import InputConfig, RobotConfig
from services.planar import Pose, check_coordinates
from services.report import Recording, pose_from_body_pose


class Stamped(msgspec.Struct, frozen=True):
    """Any recorded message, for its stamp alone."""

    tm: Time


_STAMPED = msgspec.json.Decoder(Stamped)
CHANNEL_CAPACITY = 1 << 20
"""Samples a recorded key's channel holds between two collections: seconds of any loop's output
(a full channel would make zenoh wait, and with it the loop's publisher)."""


class Recorder:
    def __init__(self, session: zenoh.Session, keys: Keys, robot: RobotConfig, limits: InputConfig) -> None:
        self._robot = robot
        self._max_coordinate = limits.max_coordinate
        recorded = (
            keys.sim_body_pose,
            keys.odometry_pose,
            keys.localization_pose,
            keys.drive_target_velocity,
            keys.motor_wheel_angles,
        )
        self._payloads: dict[str, list[bytes]] = {key: [] for key in recorded}
        self._channels = {
            key: session.declare_subscriber(key, zenoh.handlers.FifoChannel(CHANNEL_CAPACITY)) for key in recorded
        }
        self._keys = keys

    def collect(self) -> None:
        """Take the samples waiting in the channels (call often enough that they never fill up)."""
        for key, channel in self._channels.items():
            payloads = self._payloads[key]
            while (sample := channel.try_recv()) is not None:
                payloads.append(sample.payload.to_bytes())

    def collect_until(self, until_s: float, timeout_s: float) -> bool:
        """Collect until the ground truth and odometry recorded reach ``until_s`` simulated seconds
        (what the loop published up to then may still be on its way); False after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.collect()
            if all(self._reached(key, until_s) for key in (self._keys.sim_body_pose, self._keys.odometry_pose)):
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)

    def _reached(self, key: str, until_s: float) -> bool:
        payloads = self._payloads[key]
        try:
            return bool(payloads) and _STAMPED.decode(payloads[-1]).tm.to_seconds() >= until_s
        except msgspec.DecodeError:
            return False

    def close(self) -> None:
        self.collect()
        for channel in self._channels.values():
            channel.undeclare()

    def _decoded(self, key: str, message_type: type[Any], convert: Callable[[Any], Any]) -> list[Any]:
        items = []
        for payload in self._payloads[key]:
            try:
                message = decode(message_type, payload)
                items.append((message.tm.to_seconds(), convert(message)))
            except (BadInput, IndexError):
                continue  # someone else's bad input on a recorded key: not part of the run
        items.sort(key=lambda item: item[0])
        return items

    def recording(self, until: float | None = None) -> Recording:
        """The decoded series, sorted by time, cut at ``until`` simulated seconds when given."""
        keys, robot = self._keys, self._robot

        def position(message: TimedPosition) -> Pose:
            # The services refuse an implausible pose; so does the report (it would fill the plot).
            check_coordinates(message.x, message.y, self._max_coordinate)
            return Pose(message.x, message.y, message.theta)

        def wheels(message: TimedDoubleSeq) -> tuple[float, float]:
            return message.data[robot.left_wheel_id], message.data[robot.right_wheel_id]

        def command(message: TimedVelocity) -> tuple[float, float]:
            return message.vx, message.w

        recording = Recording(
            ground_truth=self._decoded(keys.sim_body_pose, TimedDoubleSeq, lambda m: pose_from_body_pose(m.data)),
            odometry=self._decoded(keys.odometry_pose, TimedPosition, position),
            localization=self._decoded(keys.localization_pose, TimedPosition, position),
            commands=[(t, *c) for t, c in self._decoded(keys.drive_target_velocity, TimedVelocity, command)],
            wheel_angles=[(t, *w) for t, w in self._decoded(keys.motor_wheel_angles, TimedDoubleSeq, wheels)],
        )
        if until is not None:
            for name in ("ground_truth", "odometry", "localization", "commands", "wheel_angles"):
                setattr(recording, name, [item for item in getattr(recording, name) if item[0] <= until])
        return recording
