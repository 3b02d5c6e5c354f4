"""The navigation section of the robot description: how the drive finds its way to a goal (the
map, the costmap from the lidar, the planner, the path tracker and the recoveries;
docs/navigation.md)."""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

from services.config.fields import (
    METRES,
    METRES_PER_SECOND,
    PER_SIMULATED_SECOND,
    RADIANS,
    SIMULATED_SECONDS,
    NonNegative,
    Positive,
    Section,
)

MAX_COSTMAP_CELLS_PER_SIDE = 2048
"""The most cells along a side of the costmap a map or ``size``/``resolution`` may give (a bound on
memory and on the work of an inflation or a plan)."""


class NavigationConfig(Section, frozen=True):
    """How a goal is reached (docs/navigation.md): a costmap (the map's obstacles, the lidar's,
    inflated), a planner on it, a path tracker (regulated pure pursuit) and recoveries when blocked.
    Scenarios never navigate: they follow their waypoints as given."""

    enabled: bool = True
    """Whether goals navigate (false: a goal is driven along the straight line from the robot to it,
    as before the navigation, and the collision monitor's hold gives it up)."""
    map: str | None = None
    """A map in map_server's format (a YAML file beside its PGM image; ``invent map`` makes one from a
    world file): its obstacles are the costmap's static layer and its extent the costmap's. None
    (``"none"``): no map, a costmap of ``size`` around the start, unknown but what the lidar has seen."""
    mapping: bool = False
    """Build a map from the lidar as the robot drives (``invent up --mapping``; services/mapping/: each
    scan matched to the map so far, correcting the odometry's drift) and publish it on ``drive/map`` as
    it grows, at ``costmap_rate``; only without ``map`` (the costmap is the lidar's, as with no map)."""
    resolution: Annotated[Positive, METRES] = 0.05
    """The costmap's cell side without a map (a map brings its own), and the built map's."""
    size: Annotated[Positive, METRES] = 20.0
    """The side of the square costmap without a map, centred on the robot's initial pose: goals
    beyond it are rejected."""
    footprint_padding: Annotated[NonNegative, METRES] = 0.05
    """Added to the body's radius for the lethal zone: a plan keeps the axle centre at least the body's
    radius plus this from every obstacle (the collision monitor's ``margin``, so that a plan never
    brings the monitor's footprint onto an obstacle)."""
    inflation_radius: Annotated[Positive, METRES] = 1.0
    """How far from an obstacle the axle centre pays a decaying cost (Nav2's ``inflation_radius``); at
    least the lethal zone's radius."""
    cost_scaling_factor: Annotated[Positive, msgspec.Meta(extra={"unit": "1/m"})] = 3.0
    """How fast the inflation's cost decays with distance beyond the lethal zone: 252·exp(−factor·d)
    (Nav2's ``cost_scaling_factor``)."""
    cost_weight: NonNegative = 3.0
    """What the planner pays for the cost: a step costs its length × (1 + cost_weight · cost/252), so
    a plan keeps its distance where it can and cuts close where it must."""
    obstacle_range: Annotated[Positive, METRES] = 3.0
    """A lidar return marks an obstacle up to this range."""
    raytrace_range: Annotated[Positive, METRES] = 3.5
    """A ray clears the cells it crosses up to this range (or its return): what moved away is forgotten."""
    replan_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 1.0
    """Plans per second of simulation time while a goal runs; a plan blocked by what the lidar sees is
    replaced at once."""
    costmap_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 1.0
    """``drive/costmap`` messages per second of simulation time while the drive runs."""
    lookahead_time: Annotated[Positive, SIMULATED_SECONDS] = 1.5
    """The path tracker's lookahead: the distance the robot covers in this time at its speed, within
    [``min_lookahead``, ``max_lookahead``] (regulated pure pursuit's adaptive lookahead)."""
    min_lookahead: Annotated[Positive, METRES] = 0.3
    """The shortest lookahead distance."""
    max_lookahead: Annotated[Positive, METRES] = 0.9
    """The longest lookahead distance."""
    regulated_min_radius: Annotated[Positive, METRES] = 0.9
    """Below this turning radius the tracker slows down in proportion (a tight turn is driven slowly)."""
    near_obstacle_speed: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.5
    """The speed's factor where the costmap's cost under the robot is highest short of lethal (it
    scales linearly from 1 at no cost): slower near obstacles."""
    min_speed: Annotated[Positive, METRES_PER_SECOND] = 0.05
    """The slowest the regulations bring the tracker's speed to (but for the final approach)."""
    rotate_to_heading_angle: Annotated[Positive, RADIANS] = math.radians(45.0)
    """When the path's direction lies further than this off the robot's heading, it turns in place first."""
    blocked_timeout: Annotated[Positive, SIMULATED_SECONDS] = 1.5
    """Held by the collision monitor, or making no progress along the plan, this long: blocked, a
    recovery begins."""
    progress_distance: Annotated[Positive, METRES] = 0.1
    """Moving less than this toward the goal in ``progress_timeout`` is no progress."""
    progress_timeout: Annotated[Positive, SIMULATED_SECONDS] = 10.0
    """How long the robot may make no progress before it counts as blocked."""
    max_recoveries: Annotated[int, msgspec.Meta(ge=0)] = 6
    """Recoveries a goal may try (clear the obstacle layer, wait, back up, spin, in turn; each then
    replans) before it ends ``aborted`` naming why."""
    wait_duration: Annotated[Positive, SIMULATED_SECONDS] = 2.0
    """The wait recovery: how long the robot stands still for the way to clear."""
    backup_distance: Annotated[Positive, METRES] = 0.3
    """The back-up recovery: how far the robot reverses (only where the costmap is clear behind it)."""
    backup_speed: Annotated[Positive, METRES_PER_SECOND] = 0.1
    """The back-up recovery's speed."""
    spin_angle: Annotated[Positive, RADIANS] = math.pi / 2.0
    """The spin recovery: how far the robot turns in place (so a narrow lidar sees around it)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_lookahead > self.max_lookahead:
            raise ValueError(
                f"`min_lookahead` = {self.min_lookahead} must not exceed `max_lookahead` = {self.max_lookahead}"
            )
        if self.size / self.resolution > MAX_COSTMAP_CELLS_PER_SIDE:
            raise ValueError(
                f"`size` / `resolution` = {self.size / self.resolution:.0f} cells a side: more than "
                f"{MAX_COSTMAP_CELLS_PER_SIDE}"
            )
        if self.mapping and self.map is not None:
            raise ValueError("`mapping` builds a map: it takes no `map` (give one or the other)")
        if self.obstacle_range > self.raytrace_range:
            raise ValueError(
                f"`obstacle_range` = {self.obstacle_range} must not exceed `raytrace_range` = {self.raytrace_range}"
            )
