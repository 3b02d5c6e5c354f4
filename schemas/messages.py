"""The four message types of docs/protocol.md section 1, mirroring the seeds' IDL field for field, and the
project's own: the bump event, the Motor methods' payloads, and what a viewer or a report needs
besides the loop's data (the sim's world, the drive's planned path, the summary of a run), and the
simulated sensors (the lidar's scan, the IMU's sample), the motor's state, a scenario's outcome and
the odometry's ``set_pose``. Goal mode's and the particle filter's are in :mod:`schemas.navigation`.

Every float must be finite: a Struct checks it in ``__post_init__``, which msgspec also runs while decoding, so a NaN or inf can
neither be built nor received.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import msgspec

NANOSECONDS_PER_SECOND = 1_000_000_000

Seconds = Annotated[int, msgspec.Meta(ge=0)]
Nanoseconds = Annotated[int, msgspec.Meta(ge=0, lt=NANOSECONDS_PER_SECOND)]

MAX_SEQUENCE_LENGTH = 32
"""The most values a TimedDoubleSeq carries: a robot's joints (wheel angles, torques), the 12 of a
body pose. Longer is bad input, refused while decoding: a 10^6-element array must not be
decoded, checked and republished."""
MAX_ID_LENGTH = 16
"""The most entries of the IIS messages' ``id`` and ``error`` arrays (unused by the services)."""
DoubleSeq = Annotated[list[float], msgspec.Meta(max_length=MAX_SEQUENCE_LENGTH)]
Ids = Annotated[list[int], msgspec.Meta(max_length=MAX_ID_LENGTH)]
Errors = Annotated[list[float], msgspec.Meta(max_length=MAX_ID_LENGTH)]


def require_finite(*values: float) -> None:
    for value in values:
        if not math.isfinite(value):
            raise ValueError(f"non-finite number {value!r}")


class Time(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """RTC::Time: a timestamp in whole seconds and nanoseconds."""

    sec: Seconds
    nsec: Nanoseconds

    @classmethod
    def from_nanoseconds(cls, total_ns: int) -> Time:
        return cls(*divmod(total_ns, NANOSECONDS_PER_SECOND))

    def to_seconds(self) -> float:
        return self.sec + self.nsec / NANOSECONDS_PER_SECOND

    def to_nanoseconds(self) -> int:
        return self.sec * NANOSECONDS_PER_SECOND + self.nsec


class TimedDoubleSeq(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """RTC::TimedDoubleSeq."""

    tm: Time
    data: DoubleSeq

    def __post_init__(self) -> None:
        require_finite(*self.data)


class TimedVelocity(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """IIS::TimedVelocity: target body velocity (vx, vy in m/s, w in rad/s)."""

    tm: Time
    id: Ids
    vx: float
    vy: float
    w: float
    error: Errors

    def __post_init__(self) -> None:
        require_finite(self.vx, self.vy, self.w, *self.error)


class TimedPosition(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """IIS::TimedPosition: a planar pose (x, y in m, theta in rad)."""

    tm: Time
    id: Ids
    x: float
    y: float
    theta: float
    error: Errors

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.theta, *self.error)


class BumpEvent(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``sim/bump``: the robot body began a contact with an obstacle (project extension).

    ``x, y, z`` is the contact point in the world frame, ``tm`` the simulation time.
    """

    tm: Time
    obstacle: str
    x: float
    y: float
    z: float

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.z)


MAX_OBSTACLES = 256
"""The most obstacles a ``sim/world`` message lists."""
MAX_PATH_POINTS = 10_000
"""The most points a ``drive/path`` message carries."""


MAX_SCAN_RAYS = 4096
"""The most rays a ``sim/scan`` carries (a 0.1° lidar has 3,600)."""
MAX_SCAN_BODIES = 1024
"""The most distinct bodies one scan names (the world's obstacles and the fleet's robots)."""
NO_HIT = -1
"""``LaserScan.hits``: the ray hit nothing within ``range_max``."""
Vector3 = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]
"""x, y, z, w."""


class LaserScan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``sim/scan``: one sweep of the robot's 2D lidar (project extension; sensor_msgs/LaserScan's
    fields). Ray ``i`` points at ``angle_min + i * angle_increment`` about the lidar frame's z (x
    forward, counter-clockwise positive); its range is in m from the lidar's origin, ``null`` where
    nothing was within ``range_max``: JSON has no infinity, and ROS's +inf (REP 117) is what the
    bridge and the viewers make of it (:meth:`ranges_or_inf`). A simulated scan also names what
    each ray hit: ``hits[i]`` indexes ``bodies`` (``NO_HIT``: nothing); a real lidar leaves both empty."""

    tm: Time
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: Annotated[list[float | None], msgspec.Meta(max_length=MAX_SCAN_RAYS)]
    bodies: Annotated[list[str], msgspec.Meta(max_length=MAX_SCAN_BODIES)] = []
    hits: Annotated[list[int], msgspec.Meta(max_length=MAX_SCAN_RAYS)] = []

    def __post_init__(self) -> None:
        require_finite(self.angle_min, self.angle_increment, self.range_min, self.range_max)
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(f"range limits [{self.range_min!r}, {self.range_max!r}] are not 0 <= min < max")
        for value in self.ranges:
            if value is not None and not 0.0 <= value < math.inf:  # NaN fails this too
                raise ValueError(f"range {value!r}: a range is finite and >= 0, or null")
        if self.hits:
            if len(self.hits) != len(self.ranges):
                raise ValueError(f"{len(self.hits)} hits for {len(self.ranges)} ranges")
            count = len(self.bodies)
            for hit in self.hits:
                if not NO_HIT <= hit < count:
                    raise ValueError(f"hit {hit} names no body of the {count} listed")
        elif self.bodies:
            raise ValueError("bodies without hits")

    def ranges_or_inf(self) -> list[float]:
        """The ranges as ROS has them: +inf where nothing was within ``range_max``."""
        return [math.inf if value is None else value for value in self.ranges]


ImuOrientationSource = Literal["none", "simulator", "estimate"]


class ImuSample(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``sim/imu``: the body's motion at the IMU, in the IMU frame (the base's axes at the mount;
    project extension, sensor_msgs/Imu's fields). ``linear_acceleration`` is the specific force an
    accelerometer measures (at rest: +9.81 m/s² on z); ``orientation`` (x, y, z, w) of the IMU frame
    in the world, as ``orientation_source`` says: ``simulator``, the simulator's ground truth
    (flagged so, since no real IMU knows its yaw); ``estimate``, a sensor's own filter; ``none``,
    not known (the quaternion is then the identity and means nothing)."""

    tm: Time
    orientation: Quaternion
    orientation_source: ImuOrientationSource
    angular_velocity: Vector3
    """rad/s about the IMU frame's x, y, z."""
    linear_acceleration: Vector3
    """m/s² along the IMU frame's x, y, z."""

    def __post_init__(self) -> None:
        require_finite(*self.orientation, *self.angular_velocity, *self.linear_acceleration)
        if self.orientation_source != "none":
            norm = math.sqrt(sum(value * value for value in self.orientation))
            if abs(norm - 1.0) > 1e-3:
                raise ValueError(f"orientation {self.orientation!r} is not a unit quaternion (norm {norm:g})")


class Obstacle(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """An obstacle of the sim's world: a ``box`` of full lengths ``size`` turned by ``yaw`` about z,
    or an upright ``cylinder`` of diameter ``size[0]`` and height ``size[2]``; centred on (x, y),
    standing on the floor (m, rad)."""

    name: str
    shape: Literal["box", "cylinder"]
    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.yaw, *self.size)


class SimWorld(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``sim/world``: the obstacles of the world the sim runs (project extension, for viewers)."""

    tm: Time
    obstacles: Annotated[list[Obstacle], msgspec.Meta(max_length=MAX_OBSTACLES)]


class PlannedPath(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/path``: the polyline the drive's scenario plans, (x, y) in m in the world frame
    (project extension, for viewers and the report)."""

    tm: Time
    scenario: str
    points: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=MAX_PATH_POINTS)]

    def __post_init__(self) -> None:
        require_finite(*(value for point in self.points for value in point))


class ServiceRestart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One restart of a service by ``invent up``'s restart policy (``--restart``; ``RunSummary.restarts``)."""

    service: str
    """The service started again, as ``up`` names its child (``motor``, ``rh1/odometry``)."""
    exit_code: int
    """How it had ended: its exit code, or minus the signal that killed it (-9: SIGKILL)."""
    wall_s: float
    """Wall seconds from the start of ``up``'s services to its new start."""
    delay_s: float
    """The delay waited before starting it again (the policy's backoff)."""


class RunSummary(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``up/run``: what ``invent up`` knows of a run besides its data, published once at its end
    so that the recording holds everything its report is built from."""

    tm: Time
    """The sim's time at the end of the run."""
    scenario: str
    mode: str
    composed: bool
    wall_time_s: float
    steps: int
    health: dict[str, Any]
    """The loop's health from the services' status replies (``report.json``'s ``health``)."""
    ended_early: Literal["", "service_died", "interrupted"] = ""
    """Why the run ended before its scenario did (a service died, Ctrl-C); empty when it did not."""
    service: str = ""
    """With ``service_died``: the service that died, as ``up`` named its child (``odometer``, ``control``)."""
    exit_code: int | None = None
    """With ``service_died``: its exit code, or minus the signal that killed it (-9: SIGKILL)."""
    restarts: tuple[ServiceRestart, ...] = ()
    """Each restart of a service by the restart policy, in order (none: no policy, or no failure)."""


MotorStateName = Literal["idle", "running", "stopped", "finished"]
StopCause = Literal["", "gui", "bump", "state_file"]


class MotorStateReport(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``motor/state``: the motor's state (docs/protocol.md section 4.6), published at every change,
    latched (project extension: what the drive gives a scenario up on)."""

    tm: Time
    """The motor's wheel-angle time when the state changed (0 before its first sample)."""
    state: MotorStateName
    stopped_by: StopCause
    """Who latched the emergency stop, while ``state`` is ``stopped``: the Motor method family
    called (``gui``, ``bump``), or ``state_file`` (restored, or the file unreadable); else ``""``."""
    held_by: str = ""
    """Why the collision monitor holds the robot (an obstacle in the stop zone, named, and where;
    or no recent scan), while it does; else ``""``. A hold is not latched: it ends when its cause does."""


ScenarioOutcomeName = Literal["completed", "aborted", "timed_out", "canceled"]


class ScenarioOutcome(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/outcome``: how the drive's scenario, or a goal, ended (project extension), latched,
    published with the drive's last command of it: ``completed``, or given up, ``aborted`` (the
    motor stayed latched stopped, or held) or ``timed_out`` (past the time limit), with the reason;
    a goal may also end ``canceled`` (a cancel, or a newer goal preempting it)."""

    tm: Time
    """The simulation time of the drive's last command."""
    scenario: str
    outcome: ScenarioOutcomeName
    reason: str
    """Why the scenario was given up (the bump and the obstacle, the limit); ``""`` when completed."""
    iteration: Annotated[int, msgspec.Meta(ge=0)]
    """The pass that ended (0: the first; a ``--loop`` scenario ends only when a pass is given up)."""
    elapsed_s: float
    """Simulated seconds of that pass (of a goal: from its start at a tick to its end)."""
    goal_id: GoalId = ""
    """The goal that ended (``drive/goal``'s ``id``), in goal mode; ``""`` for a scenario."""

    def __post_init__(self) -> None:
        require_finite(self.elapsed_s)


MAX_GOAL_ID_LENGTH = 64
GoalId = Annotated[str, msgspec.Meta(max_length=MAX_GOAL_ID_LENGTH, pattern=r"\A[A-Za-z0-9_.\-]*\Z")]
"""A goal's id: letters, digits, ``_``, ``.``, ``-``; at most 64 (a ROS goal's UUID is 32 hex digits)."""


NonNegativeGain = Annotated[float, msgspec.Meta(ge=0.0)]


class PDGains(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of the Motor interface's ``set_pd_gain``: all four gains, each finite and >= 0."""

    p_gain_l: NonNegativeGain
    p_gain_r: NonNegativeGain
    d_gain_l: NonNegativeGain
    d_gain_r: NonNegativeGain

    def __post_init__(self) -> None:
        require_finite(self.p_gain_l, self.p_gain_r, self.d_gain_l, self.d_gain_r)


class NoArguments(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of the argument-less Motor methods: ``{}`` (an empty payload is accepted too)."""


class SetOdometry(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Payload of ``odometry/set_pose``: the pose the odometry is at (as control_msgs' SetOdometry
    of diff_drive_controller's ``~/set_odometry``; a reset is (0, 0, 0)), at simulation time ``tm``."""

    x: float
    y: float
    theta: float
    tm: Time | None = None
    """When the robot was at the pose: applied as a localized pose of that stamp is (the motion
    integrated since kept on top; a stamp ahead waits for its sample); None: the last wheel-angle
    sample integrated."""

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.theta)


class SetOdometryReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Reply of ``odometry/set_pose``: taken (at stamp ``tm``), or refused and why."""

    accepted: bool
    reason: str = ""
    """Why it was refused; ``""`` when accepted."""
    tm: Time | None = None
    """The stamp it applies at; None when refused, or taken before any wheel-angle sample (then
    the pose the first sample starts from)."""
