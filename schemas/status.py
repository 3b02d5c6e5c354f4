"""The status replies (docs/protocol.md section 11): the fields every service's reply has
(:class:`ServiceStatus`, which the runtime's node fills in), and one Struct per kind of service,
built by the service and decoded by every reader (``invent up`` and its report, ``invent status``,
the benchmarks). The drive's and the ROS 2 bridge's are in :mod:`schemas.drive_status`.

A reply that does not decode as its kind's Struct is a bad reply: a reader takes it as it takes no
reply at all (:func:`decode_status`). Unknown fields are ignored, so that a reader still reads a
newer service's reply, and a user service's own fields ride beside the runtime's.
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgspec
from msgspec import UNSET, UnsetType

from schemas.messages import Time

StatusT = TypeVar("StatusT", bound="Reply")


class InputTaken(msgspec.Struct):
    """What a service took of one input, in its ``status`` (``inputs``, by key): a tool feeding it
    (``invent replay --rate 0``) waits on ``samples`` so that it never sends faster than the
    service takes."""

    every_sample: bool
    """False for an input of which only the newest sample counts (skipped samples are not taken)."""
    samples: int = 0
    """Samples handed to the service, bad ones included."""


class BadInputCount(msgspec.Struct):
    count: int
    last_reason: str


class BadInputStatus(msgspec.Struct):
    """``bad_input``: how many inputs were refused, and per key how many and the last reason (docs/protocol.md 8.1)."""

    total: int = 0
    by_key: dict[str, BadInputCount] = {}


class RealtimeStatus(msgspec.Struct):
    """``rt``: the process's real-time settings and what its garbage collector did (docs/realtime.md)."""

    enabled: bool
    policy: str
    priority: int
    memory_locked: bool
    cpus: list[int] | None
    refused: list[str]
    gc: str
    gc_collections: list[int]
    gc_max_pause_us: float
    gc_total_pause_us: float


class MemoryStatus(msgspec.Struct):
    """``memory``: the C allocator's (glibc's; ``allocator`` None and nothing else elsewhere)."""

    allocator: str | None
    in_use_mb: float | UnsetType = UNSET
    free_mb: float | UnsetType = UNSET
    trims: int | UnsetType = UNSET
    max_trim_us: float | UnsetType = UNSET


class Reply(msgspec.Struct, kw_only=True):
    """Who answers a status query."""

    service: str = ""
    robot: str = ""
    uptime_s: float = 0.0


class ServiceStatus(Reply, kw_only=True):
    """The fields every service's status has, around its own: the service builds its kind's
    Struct, and its node fills these in (``services/runtime/node.py``; the defaults are only what
    they are until then). Decoding with this type reads any service's reply, its own fields left out."""

    inputs: dict[str, InputTaken] = {}
    bad_input: BadInputStatus = msgspec.field(default_factory=BadInputStatus)
    internal_errors: int = 0
    dropped_events: int = 0
    congestion: str = "drop"
    rt: RealtimeStatus | None = None
    memory: MemoryStatus | None = None


class PlanarPose(msgspec.Struct):
    x: float
    y: float
    theta: float


class Velocity(msgspec.Struct):
    vx: float
    w: float


class LockstepHolds(msgspec.Struct):
    """Lockstep outputs held for a tick's answer, and those released unanswered (a full hold)."""

    held: int
    released_unanswered: int


class SimCounters(msgspec.Struct):
    """``sim/status``'s ``counters`` (docs/sim.md explains each)."""

    torques_applied: int = 0
    long_waits: int = 0
    missing_torques: int = 0
    stale_torques: int = 0
    bumps: int = 0
    bump_stop_calls: int = 0
    bump_stop_acks: int = 0
    bump_stop_errors: int = 0
    realtime_resyncs: int = 0
    realtime_late_steps: int = 0
    refused_participants: int = 0
    braked_steps: int = 0
    scans: int = 0
    scan_rays: int = 0
    imu_samples: int = 0


class TorqueLatencyStatus(msgspec.Struct):
    """Torque latency percentiles since the start in µs (None before the first), and the histogram."""

    samples: int
    p50_us: float | None
    p99_us: float | None
    max_us: float | None
    bin_us: float
    histogram: list[list[int]]


class LockstepParticipant(msgspec.Struct):
    rate_hz: float
    output: str
    waited_for: bool
    last_output_s: float | None
    final: bool


class DroppedParticipant(msgspec.Struct):
    """A lockstep participant whose token went while the loop ran: it is no longer waited for."""

    service: str
    sim_time_s: float


class NearestHit(msgspec.Struct):
    body: str | None
    range: float
    angle: float


class LidarStatus(msgspec.Struct):
    rate: float
    nearest: NearestHit | None


class ImuStatus(msgspec.Struct):
    rate: float


class SensorsStatus(msgspec.Struct):
    lidar: LidarStatus | None
    imu: ImuStatus | None


class SimParameters(msgspec.Struct):
    step: float
    observe_every: int
    duration: float | None
    lockstep_timeout: float
    realtime_factor: float
    torque_max_age: float
    brake_after: float | None
    max_wheel_torque: float


class SimWorldStatus(ServiceStatus, kw_only=True):
    """The part of every robot's ``sim/status`` that is the world's, the same for every robot of a
    fleet (``sim_bridge/status.py``)."""

    state: str
    engine: str
    mode: str
    world: str
    sim_time_s: float
    steps: int
    steps_per_second: float
    realtime_factor_achieved: float
    parameters: SimParameters
    fleet: list[str] | UnsetType = UNSET
    """The robots' names in a fleet sim; absent for one robot."""


class SimStatus(SimWorldStatus, kw_only=True):
    """``sim/status`` (docs/sim.md): the world's part, then the robot's."""

    motor_alive: bool
    motor_silent: bool
    torques: list[float]
    pose: PlanarPose
    counters: SimCounters
    torque_latency: TorqueLatencyStatus
    late_fraction: float
    lockstep_participants: dict[str, LockstepParticipant]
    dropped_participants: list[DroppedParticipant]
    observed_steps: int
    observed_rates: dict[str, float]
    drive_ended: bool
    braking: bool
    sensors: SensorsStatus


class MotorCounters(msgspec.Struct):
    nonfinite_torques: int
    wheel_angle_samples: int
    body_pose_samples: int
    target_velocity_samples: int
    targets_ignored: int
    command_timeouts: int
    time_base_restarts: int = 0


class MotorCoreStatus(ServiceStatus, kw_only=True):
    """The motor control's part of ``motor/status`` (``services/motor/core.py``)."""

    state: str
    output: str
    velocity_rate: float | None
    target_angle: str
    gains: dict[str, float]
    geometry: dict[str, Any]
    """The robot's wheels and the calibrated lengths (docs/motor.md)."""
    offsets: dict[str, float]
    limits: dict[str, float | None]
    command_timeout: float
    target: Velocity
    command: Velocity
    command_timed_out: bool
    counters: MotorCounters


class MotorStatus(MotorCoreStatus, kw_only=True):
    """``motor/status``, also the reply to every Motor method (docs/motor.md): the motor control's
    part, then the service's."""

    collision_monitor: CollisionMonitorStatus
    sim_alive: bool
    torques_published: int
    wheel_velocities_published: int
    lockstep_holds: LockstepHolds
    trace: str | None
    state_file: str
    restored: dict[str, Any] | None


class NearestObstacle(msgspec.Struct):
    body: str | None
    distance: float
    x: float
    y: float


class CollisionCounters(msgspec.Struct):
    scans: int
    scan_rays: int
    holds: int
    holds_by: dict[str, int]
    slowdowns: int
    bad_scans: int = 0


class CollisionMonitorStatus(msgspec.Struct, kw_only=True):
    """``motor/status``'s ``collision_monitor``: only ``enabled`` false when there is none."""

    enabled: bool
    stop_distance: float | UnsetType = UNSET
    slow_distance: float | UnsetType = UNSET
    slow_factor: float | UnsetType = UNSET
    margin: float | UnsetType = UNSET
    scan_timeout: float | UnsetType = UNSET
    min_points: int | UnsetType = UNSET
    monitoring: bool | UnsetType = UNSET
    held_by: str | None | UnsetType = UNSET
    zone: str | UnsetType = UNSET
    factor: float | UnsetType = UNSET
    last_scan_s: float | None | UnsetType = UNSET
    nearest: NearestObstacle | None | UnsetType = UNSET
    counters: CollisionCounters | UnsetType = UNSET


class OdometryVelocity(msgspec.Struct):
    v: float
    omega: float


class OdometryCounters(msgspec.Struct):
    wheel_angle_samples: int
    localization_resets: int
    pose_sets: int
    time_base_restarts: int
    lockstep_holds: LockstepHolds
    branches: dict[str, int]


class PoseSet(msgspec.Struct):
    """The last ``odometry/set_pose``: the pose, and the time it holds at (None: the starting pose)."""

    x: float
    y: float
    theta: float
    tm: Time | None


class OdometryStatus(ServiceStatus, kw_only=True):
    """``odometry/status`` (docs/odometry.md)."""

    state: str
    sim_alive: bool
    pose: PlanarPose
    velocity: OdometryVelocity
    last_wheel_angles_tm: Time | None
    last_pose_set: PoseSet | None
    counters: OdometryCounters
    parameters: dict[str, Any]
    """The robot's wheels, ``[odometry]`` and the calibrated lengths."""


class LocalizationFix(msgspec.Struct):
    t: float
    x: float
    y: float
    theta: float
    initial: bool | UnsetType = UNSET
    """The stub's: whether the fix is the initial pose."""


class AmclEstimate(msgspec.Struct):
    """The filter's estimate: its pose, and the covariance's upper triangle row by row (x, y, θ)."""

    x: float
    y: float
    theta: float
    covariance: list[float]


class AmclFilterStatus(msgspec.Struct, kw_only=True):
    particles: int
    updates: int
    resamples: int
    recoveries: int
    random_particles: int
    jumps: int
    last_jump: str


class LocalizationStatus(ServiceStatus, kw_only=True):
    """``localization/status`` (docs/localization.md): the fields of its ``mode``, ``stub``,
    ``amcl`` or ``none``; those the mode has not are absent (unset)."""

    state: str
    mode: str
    initial_pose: PlanarPose
    lockstep_participant: bool
    sim_alive: bool | UnsetType = UNSET
    rate_hz: float | UnsetType = UNSET
    seed: int | UnsetType = UNSET
    seed_from_config: bool | UnsetType = UNSET
    last_fix: LocalizationFix | None | UnsetType = UNSET
    time_base_restarts: int | UnsetType = UNSET
    # stub
    fixes_published: int | UnsetType = UNSET
    noise: dict[str, float] | UnsetType = UNSET
    first_fix_from_sim_pose: bool | None | UnsetType = UNSET
    # amcl
    estimate: AmclEstimate | UnsetType = UNSET
    filter: AmclFilterStatus | UnsetType = UNSET
    counters: dict[str, int] | UnsetType = UNSET
    # none
    initial_published_at: float | None | UnsetType = UNSET
    initial_skipped: bool | UnsetType = UNSET


class UserLockstep(msgspec.Struct):
    output: str
    rate_hz: float
    matched: bool


class UserServiceStatus(ServiceStatus, kw_only=True):
    """A user service's status: the runtime's fields (``services/extension/api.py``); the service's
    own ``status()`` fields, free-form, are merged over them on the wire, and a reader that wants
    them decodes the reply as a JSON object too."""

    sim_alive: bool
    sim_time_s: float | None
    lockstep: UserLockstep | None
    outputs: dict[str, int]
    calls: dict[str, int]


class ViewStatus(Reply, kw_only=True):
    """``view/status``: what ``invent view`` serves (docs/protocol.md 11.2)."""

    url: str
    channels: int
    messages: int
    bad_input: BadInputStatus


class ComposedServices(msgspec.Struct):
    sim: SimStatus
    motor: MotorStatus


class ControlStatus(Reply, kw_only=True):
    """``control/status``: the sim and the motor composed in one process (docs/protocol.md 11.5)."""

    state: str
    steps: int
    late_fraction: float
    internal_errors: int
    services: ComposedServices


def decode_status(status_type: type[StatusT], payload: bytes) -> StatusT | None:
    """``payload`` as ``status_type``, or None for a reply that does not decode (a bad reply, taken as no reply)."""
    try:
        return msgspec.json.decode(payload, type=status_type)
    except (msgspec.ValidationError, msgspec.DecodeError):
        return None
