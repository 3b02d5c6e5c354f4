"""A map from a run's recorded messages (pure: no file, no zenoh; ``invent map --from`` reads the
file and hands them here).

The robot's scans (``invent/<robot>/sim/scan``, LaserScan) and odometry poses
(``invent/<robot>/odometry/pose``, TimedPosition, one per observed step) are merged in stamp order and
fed to a :class:`~services.mapping.builder.MapBuilder`, which pairs each scan with the odometry pose
interpolated at its stamp and corrects it by scan matching. A recording of a fleet holds several
robots: one is named, or the only one is taken. A message that does not decode is someone's bad
input, not part of the run, and is skipped. Every refusal is a ConfigError naming why.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

from schemas.codec import BadInput, decode
from schemas.keys import Keys, Topic, parse_data_key
from schemas.messages import LaserScan, TimedPosition
from services.errors import ConfigError
from services.mapping.builder import CENTRED, DEFAULT_RESOLUTION, DEFAULT_SETTINGS, LidarMount, MapBuilder
from services.mapping.matcher import MatcherSettings
from services.planar import Pose

Decoded = TypeVar("Decoded", LaserScan, TimedPosition)

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
    odometry_poses: int
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
    mount: LidarMount = CENTRED,
    settings: MatcherSettings = DEFAULT_SETTINGS,
    progress: Callable[[str], None] | None = None,
) -> RunMap:
    """The map of ``robot``'s scans (the only robot's by default) corrected by scan matching;
    ``progress`` is told every 10 % of the scans. ConfigError when there is no robot, no scan or no
    odometry pose to build from."""
    name = choose_robot(messages, robot)
    keys = Keys(name)
    scans = _decoded(messages, keys.topic(Topic.SIM_SCAN), LaserScan)
    poses = _decoded(messages, keys.topic(Topic.ODOMETRY_POSE), TimedPosition)
    if not scans:
        raise ConfigError(f"it holds no scans of robot {name!r} ({keys.sim_scan}): a map is made of scans")
    if not poses:
        raise ConfigError(
            f"it holds no odometry poses of robot {name!r} ({keys.odometry_pose}): the scans' poses come from them"
        )
    builder = MapBuilder(resolution, mount, settings)
    # by stamp; at one stamp the odometry first, so that a scan finds its pose at once
    events: list[tuple[int, int, TimedPosition | LaserScan]] = [
        *((pose.tm.to_nanoseconds(), 0, pose) for pose in poses),
        *((scan.tm.to_nanoseconds(), 1, scan) for scan in scans),
    ]
    events.sort(key=lambda event: (event[0], event[1]))
    told = 0
    scans_fed = 0
    for stamp_ns, _, message in events:
        if isinstance(message, TimedPosition):
            builder.add_odometry(stamp_ns, Pose(message.x, message.y, message.theta))
            continue
        builder.add_scan(message)
        scans_fed += 1
        if progress is not None and scans_fed * PROGRESS_STEPS >= (told + 1) * len(scans):
            told = scans_fed * PROGRESS_STEPS // len(scans)
            progress(f"{told * 100 // PROGRESS_STEPS} % of {len(scans)} scans")
    builder.finish()
    return RunMap(name, len(scans), len(poses), builder)


def _decoded(messages: Sequence[Recorded], key: str, message_type: type[Decoded]) -> list[Decoded]:
    found: list[Decoded] = []
    for message in messages:
        if message.topic == key:
            try:
                found.append(decode(message_type, message.data))
            except BadInput:
                continue
    return found
