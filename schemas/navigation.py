"""The messages of goal mode and of the particle filter (docs/protocol.md sections 7.1 and 7.3),
beside the loop's in :mod:`schemas.messages`: a goal, its reply, cancel, start and feedback; the
drive's map, costmap and plan; the localization's initial pose, its reply and its particles.

Every float must be finite, checked in ``__post_init__`` as the loop's messages are.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from schemas.messages import MAX_PATH_POINTS, GoalId, Time, require_finite

PositiveFloat = Annotated[float, msgspec.Meta(gt=0.0)]
GoalFrame = Literal["map", "odom"]
"""The frame of a goal's pose (docs/protocol.md section 7.3): ``map`` is the world frame of
``odometry/pose`` and the simulator; ``odom`` is the frame in which the robot started at the origin
facing +x (the configured initial pose is ``odom``'s origin in ``map``)."""


MAX_GOAL_SECONDS = 1e9
"""The most simulated seconds a goal's ``time_limit`` (and a goal file's ``at``, a scenario file's
time limit and durations) may say, about 32 years: its nanoseconds stay within int64 and its
seconds within a ROS Duration's int32, where ``1e308`` s overflowed the drive's conversion to nanoseconds."""


class GoalRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Payload of ``drive/goal/send``: where to go. Omitted fields take the ``[goals]`` defaults."""

    x: float
    y: float
    theta: float | None = None
    """The heading to end at (rad); None: any heading (the goal ends where it arrives)."""
    frame: str = "map"
    """:data:`GoalFrame`; another is rejected (a string here so that the reply can name it)."""
    position_tolerance: float | None = None
    """m; > 0; None: ``goals.position_tolerance``."""
    heading_tolerance: float | None = None
    """rad; > 0; None: ``goals.heading_tolerance``."""
    time_limit: float | None = None
    """Simulated seconds the goal may take; > 0, at most :data:`MAX_GOAL_SECONDS`; None: the drive's
    rule (as for a scenario)."""
    id: GoalId = ""
    """The caller's id for the goal (a ROS goal's UUID); ``""``: the drive makes one."""


class GoalReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Reply of ``drive/goal/send``: accepted (with its id), or rejected and why."""

    accepted: bool
    id: str
    """The goal's id when accepted (the caller's, or the drive's ``g<n>``); ``""`` when rejected."""
    reason: str = ""
    """Why the goal was rejected; ``""`` when accepted."""


class CancelRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of ``drive/goal/cancel``: the goal to cancel; ``""`` (or an empty payload): whatever runs."""

    id: GoalId = ""


class CancelReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Reply of ``drive/goal/cancel``: the goals now canceling (none, or the one that ran), or why none."""

    canceling: list[str]
    reason: str = ""
    """Why nothing is canceling (no goal runs, an unknown id, the goal already ended); ``""`` otherwise."""


class GoalTarget(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/goal``: the goal the drive has started, in ``map`` (latched; project extension)."""

    tm: Time
    """The tick at which the goal started."""
    id: GoalId
    x: float
    y: float
    theta: float | None
    frame: str
    """The frame the goal was given in (its pose here is already in ``map``)."""
    position_tolerance: PositiveFloat
    heading_tolerance: PositiveFloat
    time_limit_s: PositiveFloat | None

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.position_tolerance, self.heading_tolerance)
        for value in (self.theta, self.time_limit_s):
            if value is not None:
                require_finite(value)


GoalStateName = Literal["executing", "canceling"]


class GoalFeedback(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/goal/feedback``: a running goal's progress, at ``goals.feedback_rate`` per simulated second."""

    tm: Time
    id: GoalId
    state: GoalStateName
    x: float
    y: float
    theta: float
    """The robot's pose (``odometry/pose``, in ``map``)."""
    distance_remaining: float
    """m along the plan while the goal navigates, else straight to the goal's position."""
    elapsed_s: float
    """Simulated seconds since the goal started."""
    estimated_remaining_s: float
    """Simulated seconds still needed by the drive's plan (turn, drive, turn) from here."""
    recoveries: Annotated[int, msgspec.Meta(ge=0)] = 0
    """Recoveries the goal's navigation has tried so far (NavigateToPose's ``number_of_recoveries``)."""

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.theta, self.distance_remaining, self.elapsed_s, self.estimated_remaining_s)


MAX_GRID_CELLS = 4_194_304
"""The most cells an ``OccupancyGrid`` carries (2048 x 2048: 102 m square at 5 cm)."""
OCCUPANCY_UNKNOWN = -1
"""``OccupancyGrid.data``: a cell nobody has seen (stored as the byte 255)."""
_OCCUPANCY_BYTES = bytes(range(101)) + bytes([255])


class OccupancyGrid(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/map`` and ``drive/costmap``: a grid of cells over the ``map`` frame (project extension;
    nav_msgs/OccupancyGrid's fields). Cell (col, row) covers [origin_x + col·resolution, + resolution)
    × [origin_y + row·resolution, + resolution); ``data`` is row-major from row 0 (the lowest y), one
    signed byte a cell: 0 (free) to 100 (occupied, or a costmap's lethal cost), -1 unknown (the byte
    255). JSON carries the bytes as base64."""

    tm: Time
    resolution: PositiveFloat
    """Metres per cell side."""
    width: Annotated[int, msgspec.Meta(ge=1)]
    """Cells along x."""
    height: Annotated[int, msgspec.Meta(ge=1)]
    """Cells along y."""
    origin_x: float
    """The map-frame x of cell (0, 0)'s lower-left corner, m."""
    origin_y: float
    data: bytes

    def __post_init__(self) -> None:
        require_finite(self.resolution, self.origin_x, self.origin_y)
        cells = self.width * self.height
        if cells > MAX_GRID_CELLS:
            raise ValueError(f"{self.width} x {self.height} cells: more than {MAX_GRID_CELLS}")
        if len(self.data) != cells:
            raise ValueError(f"{len(self.data)} bytes of data for {self.width} x {self.height} cells")
        if self.data.translate(None, _OCCUPANCY_BYTES):
            raise ValueError("a cell is neither -1 (unknown) nor 0 to 100")


class GoalPlan(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``drive/plan``: the path the drive's planner has for the running goal, from the robot to the
    goal, (x, y) in m in ``map`` (project extension; nav_msgs/Path's poses), latched; published at
    each plan and, empty, when the goal ends."""

    tm: Time
    goal_id: GoalId
    points: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=MAX_PATH_POINTS)]

    def __post_init__(self) -> None:
        require_finite(*(value for point in self.points for value in point))


MAX_PARTICLES = 20_000
"""The most particles a ``localization/particles`` message carries (``amcl.max_particles`` is at most this)."""
COVARIANCE_LENGTH = 6
"""A planar pose's covariance as sent: the upper triangle of the 3 × 3 matrix over (x, y, θ), row by
row: xx, xy, xθ, yy, yθ, θθ (m², m², m·rad, m², m·rad, rad²)."""
Covariance = Annotated[list[float], msgspec.Meta(max_length=COVARIANCE_LENGTH)]


class InitialPose(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Payload of ``localization/initial_pose``: where the robot is, about (RViz's "2D Pose Estimate",
    ROS's ``/initialpose``). The filter is seeded again around it, whenever it comes."""

    x: float
    y: float
    theta: float
    covariance: Covariance = msgspec.field(default_factory=list)
    """:data:`COVARIANCE_LENGTH` values (xx, xy, xθ, yy, yθ, θθ), or none: ``amcl.initial_sigma_xy``
    and ``amcl.initial_sigma_theta``."""

    def __post_init__(self) -> None:
        require_finite(self.x, self.y, self.theta, *self.covariance)
        if self.covariance and len(self.covariance) != COVARIANCE_LENGTH:
            raise ValueError(f"covariance has {len(self.covariance)} values, not {COVARIANCE_LENGTH} (or none)")


class LocalizationReply(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Reply of ``localization/initial_pose`` and ``localization/global_localization``: taken, or
    refused and why."""

    accepted: bool
    reason: str = ""
    """Why it was refused; ``""`` when accepted."""


ParticleValues = Annotated[list[float], msgspec.Meta(max_length=MAX_PARTICLES)]


class ParticleCloud(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``localization/particles``: the filter's particles in the ``map`` frame (project extension;
    nav2_amcl's ``/particle_cloud``), one entry per particle in each list; the weights sum to 1."""

    tm: Time
    x: ParticleValues
    y: ParticleValues
    theta: ParticleValues
    weight: ParticleValues

    def __post_init__(self) -> None:
        require_finite(*self.x, *self.y, *self.theta, *self.weight)
        if not len(self.x) == len(self.y) == len(self.theta) == len(self.weight):
            raise ValueError("x, y, theta and weight must have one entry per particle")
