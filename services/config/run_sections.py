"""The sections of the robot description around the loop: how ROS 2 sees the robot, what a run
records, and the real-time settings of the control path's processes."""

from __future__ import annotations

import math
import re
from enum import StrEnum
from typing import Annotated, Literal

import msgspec

from services.config.fields import (
    MEGABYTES,
    PER_SIMULATED_SECOND,
    SIMULATED_SECONDS,
    NonNegative,
    Positive,
    Section,
)

Covariance = tuple[NonNegative, NonNegative, NonNegative, NonNegative, NonNegative, NonNegative]
"""The diagonal of a 6x6 covariance (x, y, z, roll, pitch, yaw), as diff_drive_controller takes it."""
FrameId = Annotated[str, msgspec.Meta(pattern=r"\A[A-Za-z0-9_][A-Za-z0-9_/]*\Z")]


NAMESPACE = re.compile(r"\A(/?[A-Za-z][A-Za-z0-9_]*)*/?\Z")
"""A ROS namespace: "" (none), or names of letters, digits and underscores, each starting with a
letter, joined by ``/`` (a leading or trailing ``/`` is the same namespace)."""


class TfLayout(StrEnum):
    """Where a namespaced ROS 2 bridge publishes its transforms (``ros2.tf``, docs/ros2.md)."""

    NAMESPACED = "namespaced"
    PREFIXED = "prefixed"


class Ros2Config(Section, frozen=True):
    """``invent ros2``: the robot as ROS 2 sees it over rmw_zenoh (docs/ros2.md)."""

    namespace: Annotated[str, msgspec.Meta(pattern=NAMESPACE.pattern)] = ""
    """ROS namespace of the bridge's node, topics and services (``--namespace``): "" = none, or
    names of letters, digits and underscores (each starting with a letter) joined by ``/``."""
    node_name: Annotated[str, msgspec.Meta(pattern=r"\A[A-Za-z][A-Za-z0-9_]*\Z")] = "invent_bridge"
    """Name of the bridge's node in the ROS graph (in ``namespace``)."""
    tf: TfLayout = TfLayout.NAMESPACED
    """How a bridge in a namespace publishes TF (with no namespace both are ``/tf`` and ``/tf_static``,
    frames as named): ``namespaced`` on ``<ns>/tf`` and ``<ns>/tf_static`` with the frames as named,
    as Nav2's multi-robot bringup has it; ``prefixed`` on the shared ``/tf`` and ``/tf_static`` with
    the robot's frames prefixed ``<ns>/`` (``map`` stays the world's), for one RViz showing every robot."""
    publish_clock: bool = True
    """Whether this bridge publishes ``/clock``: one per ROS domain should (in a fleet, the first robot's)."""
    distro: Literal["jazzy", "kilted", "rolling", "humble"] = "jazzy"
    """The ROS 2 release of the nodes to talk to: Humble's rmw_zenoh has no type hashes and writes
    ``TypeHashNotSupported`` in their place in keys and tokens; the others the RIHS01 hash."""
    map_frame: FrameId = "map"
    """The world's fixed frame: the parent of ``odom_frame`` in the ``map -> odom`` transform the
    bridge derives from ``odometry/pose``."""
    odom_frame: FrameId = "odom"
    """The odometry's frame: ``/odom``'s frame and the parent of ``base_frame`` in TF."""
    base_frame: FrameId = "base_link"
    """The robot's root frame (the axle centre, as the sim's body pose); the URDF's root link."""
    scan_frame: FrameId = "base_scan"
    """The lidar's frame (``scan``'s ``frame_id``): a fixed joint from ``base_frame`` at the ``[lidar]``
    mount in the URDF and on ``tf_static``, named as TurtleBot3's."""
    imu_frame: FrameId = "imu_link"
    """The IMU's frame (``imu``'s ``frame_id``): a fixed joint from ``base_frame`` at the ``[imu]``
    mount, named as TurtleBot3's."""
    publish_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 50.0
    """``/odom``, ``/tf`` and ``/joint_states`` per second of simulation time (diff_drive_controller's
    ``publish_rate``)."""
    clock_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 100.0
    """``/clock`` messages per second of simulation time: the resolution of ROS time with ``use_sim_time``."""
    cmd_vel_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 50.0
    """The most ``/cmd_vel`` messages forwarded as target velocities per second of simulation time;
    between two, only the newest is kept (a flood is coalesced and counted)."""
    pose_covariance: Covariance = (0.001, 0.001, 0.001, 0.001, 0.001, 0.01)
    """``/odom`` pose covariance diagonal (diff_drive_controller's default)."""
    twist_covariance: Covariance = (0.001, 0.001, 0.001, 0.001, 0.001, 0.01)
    """``/odom`` twist covariance diagonal (diff_drive_controller's default)."""
    enable_odom_tf: bool = True
    """Whether the bridge publishes ``odom_frame -> base_frame`` on TF (diff_drive_controller's
    ``enable_odom_tf``); off, a node of one's own (robot_localization's ekf_node fusing ``/odom``)
    publishes it. ``/odom`` is published either way."""
    enable_map_odom_tf: bool = True
    """Whether the bridge publishes ``map_frame -> odom_frame`` on TF (from ``odometry/pose``); off,
    a localization of one's own (slam_toolbox, nav2_amcl, robot_localization) publishes it."""
    enable_wheel_tf: bool = True
    """Whether the bridge publishes ``base_frame -> <wheel>`` on TF; off, robot_state_publisher
    publishes them from ``/robot_description`` and ``/joint_states`` (both published either way)."""
    navigate_to_pose: bool = True
    """Whether the bridge serves the ``navigate_to_pose`` action and subscribes ``goal_pose``; off,
    neither is declared (no token either), and Nav2's bt_navigator may serve both."""
    result_timeout: Annotated[Positive, SIMULATED_SECONDS] = 900.0
    """How long an ended NavigateToPose goal's status and result are kept (rcl_action's
    ``result_timeout``, Nav2's 900 s): its ``get_result`` answered, its UUID not taken again."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("pose_covariance", "twist_covariance"):
            if not all(math.isfinite(value) for value in getattr(self, name)):
                raise ValueError(f"`{name}` must be finite")


class RecordRate(StrEnum):
    """How much of a run is recorded (``record.rate``)."""

    OBSERVED = "observed"
    EVERY_STEP = "every_step"


class RecordKeep(StrEnum):
    """What a recording keeps once ``record.max_size`` is written (``record.keep``)."""

    UNTIL_FULL = "until_full"
    """The oldest: the recording stops there (but for what says how the run ended), the run goes on."""
    NEWEST = "newest"
    """The newest: its oldest files are removed, whole, as new ones are written."""


MIN_ROTATED_FILE_MB = 1.0
"""The smallest file a recording that keeps the newest rotates (``record.split_size``): a few of
the journals' batches and the MCAP file's chunks."""
ROTATED_FILES = 8
"""With ``record.keep = "newest"`` and no ``split_size``: ``max_size`` in this many files."""


class RecordConfig(Section, frozen=True):
    """What ``invent up`` records (its ``run.mcap``, and the journals the services keep meanwhile:
    docs/recording.md, "Rates and bounds")."""

    rate: RecordRate = RecordRate.OBSERVED
    """``observed``: every key at the observed steps (``sim.observe_every``), as the loop publishes
    them, what the report, plots and views need; ``every_step``: the control path and the poses at
    every simulation step too, for debugging the loop (about ten times the size)."""
    max_size: Annotated[Positive, MEGABYTES] | None = 1024.0
    """The most a recording holds: what ``keep`` keeps then; the journals of the run share it
    (equally with ``until_full``, by what each writes with ``newest``)."""
    keep: RecordKeep = RecordKeep.UNTIL_FULL
    """At ``max_size``: ``until_full`` stops the recording there (the run goes on); ``newest``
    removes the recording's oldest files, whole, to stay within it (its files split at
    ``split_size``, or in eight if none): a run left going for days keeps its last hours.
    ``invent up --goals``, ``--goal-file`` and ``--loop`` set ``newest`` unless told otherwise."""
    max_duration: Annotated[Positive, SIMULATED_SECONDS] | None = None
    """Nothing stamped later is recorded."""
    split_size: Annotated[Positive, MEGABYTES] | None = None
    """A new file of the recording (``run_1.mcap``, ...) once a file has this much."""
    split_duration: Annotated[Positive, SIMULATED_SECONDS] | None = None
    """Simulation time each file of the recording covers."""
    min_free_disk: Annotated[NonNegative, MEGABYTES] = 256.0
    """The recording stops when less than this is free on its disk (the run goes on)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.keep != RecordKeep.NEWEST:
            return
        if self.max_size is None:
            raise ValueError('`max_size` must be set with `keep = "newest"`: the oldest files go past it')
        if self.rotation_size < MIN_ROTATED_FILE_MB:
            raise ValueError(
                f"`split_size` ({self.rotation_size:g} MB) must be at least {MIN_ROTATED_FILE_MB:g} MB with "
                '`keep = "newest"`: the smallest file it rotates'
            )
        if self.max_size < 2 * self.rotation_size:
            raise ValueError(
                f"`max_size` ({self.max_size:g} MB) cannot hold two files of `split_size` ({self.rotation_size:g} MB) "
                'with `keep = "newest"`: one whole file kept while the next is written'
            )

    @property
    def every_step(self) -> bool:
        return self.rate is RecordRate.EVERY_STEP

    @property
    def keeps_newest(self) -> bool:
        return self.keep == RecordKeep.NEWEST

    @property
    def rotation_size(self) -> float:
        """MB of messages per file when the newest are kept: ``split_size``, or ``max_size`` in
        :data:`ROTATED_FILES` files."""
        if self.split_size is not None:
            return self.split_size
        return (self.max_size or 0.0) / ROTATED_FILES

    def journal_max_bytes(self, share: int) -> int | None:
        """What one of ``share`` journals of a run may hold: its equal share with ``until_full``; with
        ``newest`` the whole budget, which the journals' files share by what each writes."""
        if self.max_size is None:
            return None
        return round(self.max_size * 1_000_000 / (1 if self.keeps_newest else share))

    def journal_file_bytes(self, share: int) -> int | None:
        """With ``newest``: where one of ``share`` journals goes on in a new file (together, one
        ``rotation_size``); None otherwise."""
        return round(self.rotation_size * 1_000_000 / share) if self.keeps_newest else None


class GcPolicy(StrEnum):
    """What Python's garbage collector does in a real-time process (``rt.gc``)."""

    AUTOMATIC = "automatic"
    FROZEN = "frozen"
    IDLE = "idle"


CpuId = Annotated[int, msgspec.Meta(ge=0)]


class CpuChoice(StrEnum):
    LAST = "last"
    """The last CPU the process may use: every process of the control path on that same one."""
    ANY = "any"
    """Wherever the system likes."""


class RtConfig(Section, frozen=True):
    """Real-time settings of the control path's processes (``--rt``: the sim, the motor, the router;
    docs/realtime.md). Opt-in; what the system refuses is said in one line and skipped."""

    enabled: bool = False
    """SCHED_FIFO, locked memory, the CPUs and the collector below (``--rt`` sets it)."""
    priority: Annotated[int, msgspec.Meta(ge=1, le=99)] = 50
    """SCHED_FIFO priority (ros2_control's controller manager runs at 50)."""
    lock_memory: bool = True
    """``mlockall``: every page of the process kept in memory, now and later."""
    cpus: tuple[CpuId, ...] | CpuChoice = CpuChoice.LAST
    """CPUs the process runs on (its threads too): a list, ``"last"`` (the last CPU it may use, so
    that the control path's processes share one core and hand each step over without waking
    another: measured the best here, docs/realtime.md) or ``"any"`` (wherever the system likes)."""
    gc: GcPolicy = GcPolicy.FROZEN
    """Python's garbage collector: ``automatic`` (as ever), ``frozen`` (what start-up made is frozen
    and never scanned again), ``idle`` (frozen, and the young generation collected when the service
    thread is about to wait; automatic collections only as a safety net)."""
    partition: bool = True
    """With or without ``enabled``: the control path's processes (the sim, the motor, the router)
    on ``cpus``, and every other process of the stack (the other services, the ROS 2 bridge, the
    view, the recorder, your own services) on the CPUs left, so that no observer's thread is ever
    woken on the core a step's exchange runs on (CPU affinity needs no privilege). Nothing is pinned
    with a single CPU or ``cpus = "any"``."""
