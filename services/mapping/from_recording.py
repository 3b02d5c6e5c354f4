"""A map from a run's recorded messages (pure: no file, no zenoh; ``invent map --from`` reads the
file and hands them here).

The robot's scans (``invent/<robot>/sim/scan``, LaserScan) are merged in stamp order with its motion
and fed to a :class:`~services.mapping.builder.MapBuilder`, which pairs each scan with the pose
interpolated at its stamp and corrects it by scan matching; the finished map is then put where the
run started (:meth:`~services.mapping.builder.MapBuilder.anchor`). The motion is the wheels' angles
(``motor/wheel_angles``) integrated by the odometry's own core with the robot's description, from
the odometry's first pose: the wheels alone, as a SLAM's odometry is. A recording without them (a
filtered one) falls back on the odometry's poses (``odometry/pose``), whose resets by a localization
the builder takes out as best it can: a localization's small corrections stay in them, and on the
three_rooms tour (amcl) the map lay 6 cm off in the far room from them, 2 cm from the wheels.

A recording of a fleet holds several robots: one is named, or the only one is taken. A message that
does not decode is someone's bad input, not part of the run, and is skipped, as is a wheel sample the
odometry refuses. Every refusal is a ConfigError naming why.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

from schemas.codec import BadInput, decode
from schemas.keys import Keys, parse_data_key
from schemas.messages import LaserScan, TimedDoubleSeq, TimedPosition
from schemas.topics import Topic
from services.config import Config
from services.errors import ConfigError
from services.mapping.builder import DEFAULT_RESOLUTION, DEFAULT_SETTINGS, LidarMount, MapBuilder
from services.mapping.matcher import MatcherSettings
from services.odometry.core import Odometry
from services.planar import Pose

Decoded = TypeVar("Decoded", LaserScan, TimedDoubleSeq, TimedPosition)

PROGRESS_STEPS = 10
"""Progress is told this many times over a run's scans (every 10 %)."""


class Recorded(Protocol):
    """A recorded message as services.recording.mcap_files reads it: its channel and payload."""

    @property
    def topic(self) -> str: ...

    @property
    def data(self) -> bytes: ...


@dataclass(frozen=True)
class RunMap:
    """What a run's map was built from, and the builder holding it (its grid, poses and counters)."""

    robot: str
    scans: int
    motion: str
    """The key the motion came from: the wheels' angles, or the odometry's poses."""
    motion_samples: int
    """The samples of it that moved the builder."""
    anchor: Pose | None
    """How the finished map was moved to lie where the run started (None: not moved)."""
    builder: MapBuilder


def robots_of(messages: Iterable[Recorded]) -> list[str]:
    """The robots whose data keys a recording holds, sorted."""
    return sorted({parsed[0] for message in messages if (parsed := parse_data_key(message.topic)) is not None})


def choose_robot(messages: Sequence[Recorded], robot: str | None) -> str:
    """``robot``, or the recording's only robot; ConfigError naming the robots otherwise."""
    robots = robots_of(messages)
    if not robots:
        raise ConfigError("it is not a run's recording: it holds no robot's data keys (invent/<robot>/...)")
    if robot is None:
        if len(robots) > 1:
            raise ConfigError(f"it holds several robots ({', '.join(robots)}): name one with --robot")
        return robots[0]
    if robot not in robots:
        raise ConfigError(f"it holds no robot {robot!r}; its robots: {', '.join(robots)}")
    return robot


def build_map(
    messages: Sequence[Recorded],
    robot: str | None = None,
    resolution: float = DEFAULT_RESOLUTION,
    config: Config | None = None,
    settings: MatcherSettings = DEFAULT_SETTINGS,
    progress: Callable[[str], None] | None = None,
) -> RunMap:
    """The map of ``robot``'s scans (the only robot's by default) corrected by scan matching and
    anchored at the start; ``config``: the robot's description (its wheels, axle, odometry settings and
    lidar mount; the defaults when None); ``progress`` is told every 10 % of the scans. ConfigError
    when there is no robot, no scan or no motion to build from."""
    name = choose_robot(messages, robot)
    config = config if config is not None else Config()
    keys = Keys(name)
    scans = _decoded(messages, keys.topic(Topic.SIM_SCAN), LaserScan)
    wheels = _decoded(messages, keys.topic(Topic.MOTOR_WHEEL_ANGLES), TimedDoubleSeq)
    poses = _decoded(messages, keys.topic(Topic.ODOMETRY_POSE), TimedPosition)
    if not scans:
        raise ConfigError(f"it holds no scans of robot {name!r} ({keys.sim_scan}): a map is made of scans")
    if not wheels and not poses:
        raise ConfigError(
            f"it holds no wheel angles ({keys.motor_wheel_angles}) nor odometry poses ({keys.odometry_pose}) "
            f"of robot {name!r}: the scans' poses come from them"
        )
    builder = MapBuilder(resolution, LidarMount.of(config.lidar), settings)
    motion = _WheelMotion(config, poses) if wheels else _PoseMotion()
    # by stamp; at one stamp the motion first, so that a scan finds its pose at once
    events: list[tuple[int, int, TimedDoubleSeq | TimedPosition | LaserScan]] = [
        *((sample.tm.to_nanoseconds(), 0, sample) for sample in (wheels or poses)),
        *((scan.tm.to_nanoseconds(), 1, scan) for scan in scans),
    ]
    events.sort(key=lambda event: (event[0], event[1]))
    told = 0
    scans_fed = 0
    for stamp_ns, _, message in events:
        if isinstance(message, LaserScan):
            builder.add_scan(message)
            scans_fed += 1
            if progress is not None and scans_fed * PROGRESS_STEPS >= (told + 1) * len(scans):
                told = scans_fed * PROGRESS_STEPS // len(scans)
                progress(f"{told * 100 // PROGRESS_STEPS} % of {len(scans)} scans")
        elif (pose := motion.pose(stamp_ns, message)) is not None:
            builder.add_odometry(stamp_ns, pose)
    builder.finish()
    anchor = builder.anchor(scans)
    source = keys.motor_wheel_angles if wheels else keys.odometry_pose
    return RunMap(name, len(scans), source, motion.taken, anchor, builder)


class _PoseMotion:
    """The odometry's poses as they were recorded."""

    def __init__(self) -> None:
        self.taken = 0

    def pose(self, stamp_ns: int, message: TimedDoubleSeq | TimedPosition) -> Pose | None:
        assert isinstance(message, TimedPosition)
        self.taken += 1
        return Pose(message.x, message.y, message.theta)


class _WheelMotion:
    """The wheels' angles integrated by the odometry's core, from the odometry's first recorded pose
    (else the configured start); a sample it refuses, or one not later than the last, is skipped."""

    def __init__(self, config: Config, poses: Sequence[TimedPosition]) -> None:
        start = (
            Pose(poses[0].x, poses[0].y, poses[0].theta)
            if poses
            else Pose(config.odometry.initial_x, config.odometry.initial_y, config.odometry.initial_theta)
        )
        self._odometry = Odometry(config.robot, config.odometry, start=start, limits=config.input)
        self._last_ns: int | None = None
        self.taken = 0

    def pose(self, stamp_ns: int, message: TimedDoubleSeq | TimedPosition) -> Pose | None:
        assert isinstance(message, TimedDoubleSeq)
        if self._last_ns is not None and stamp_ns <= self._last_ns:
            return None
        try:
            self._odometry.step(stamp_ns, message.data)
        except BadInput:
            return None
        self._last_ns = stamp_ns
        self.taken += 1
        return self._odometry.pose


def _decoded(messages: Sequence[Recorded], key: str, message_type: type[Decoded]) -> list[Decoded]:
    found: list[Decoded] = []
    for message in messages:
        if message.topic == key:
            try:
                found.append(decode(message_type, message.data))
            except BadInput:
                continue
    return found
