"""Scan-to-map matching (pure: numpy, scipy.ndimage): the pose at which a scan's points best lie on
the surfaces of the map built so far, found from a prior (the odometry's motion since the last scan
added to that scan's corrected pose).

What a scan is matched against (:class:`SurfaceField`), over a window around the prior only (a
scan reaches ``range_max``: the rest of the map cannot matter):

* each occupied cell's **surface point**, the mean of the hits it took, finer than the cell (a cell
  centre is up to half a cell off the wall, and a match to centres creeps by that much wherever the
  map constrains a direction weakly, as in a doorway);
* its **normal**, of the line through its neighbours' surface points seen from its side (none at a
  corner or an end), turned to the side the surface was seen from;
* for each **facing** (which way the rays that hit it travelled: +x, −x, +y, −y), the nearest
  occupied cell of that facing to every cell (``scipy.ndimage.distance_transform_edt`` and its
  indices): a point's correspondence is looked up in O(1), and is refused when it lies on the other
  side of its surface from the lidar. Both keep a scan off the far face of a thin wall (two cells
  away), which otherwise pulls it a wall's thickness at every doorway.

The pose is then refined by **Gauss–Newton** (point-to-line ICP): each point's residual is its
distance to its surface along the normal, weighed by Cauchy's kernel (something new, not yet on the
map, counts little), plus the prior's term (a direction the scan does not constrain keeps the
prior's value rather than drifting on noise). A point whose surface makes no line (a corner, a door
jamb's end) is left out.

Passing a door of a thin wall, the map constrains the direction through the door by little else
than the wall's faces and jambs, and two things pulled the match back the way it came (the map came
out short along the rooms, 4.6 cm on tests/mapping_world.py's three_rooms tour, 8 to 9 cm on a
simulator run through both doors and back):

* a thin wall's two faces (0.1 m: two cells apart) fitted in one neighbourhood made no line, so the
  face newly seen from the door was matched point-to-point to the other face's surface points, which
  the side check (the cell's mean view) let through: normals are now fitted over the neighbours
  seen from the cell's side only (:func:`_normals`);
* a corner's or jamb end's surface point is the mean of the hits taken from where it was seen so far,
  and a point-to-point match to it pulls the pose back there (a few mm a scan, every scan through
  the door): such points are no longer matched.

Measured with a map built at the true poses, each scan matched from its true pose: the x bias summed
over the three_rooms tour went from −0.32 m to +0.02 m. The tour's map: 11.904 to 11.909 m between
the outer walls' cells before, 11.921 to 11.924 after (11.95 true; what is left, about 1 cm in room 1
and 1 to 2 cm more by room 3, builds up without a door in sight: a wall on a cell's edge splits its
hits, the cell in front is often cleared, and the mean left behind lies deeper than the wall; lending
the cleared cells' hits to the cell behind was tried and measured worse). A simulator run (odometry
drifting, lidar σ = 0.01 m, room 1 to 3 and back): the corrected pose's x error at most −8.2 cm
before, −2.5 cm after.

What is left is a few millimetres a scan, against a map of few scans where the robot has just come
(its start, a room seen first through a door), and a prior loose enough lets each match keep it: the
prior (``prior_xy_sigma``, ``prior_theta_sigma``) now trusts the wheels' motion over one scan as it
deserves, and the finished map is anchored at the start (:meth:`~services.mapping.builder.MapBuilder.anchor`).
On the simulator's three_rooms tour (amcl's run, the wheels' angles for the motion): the corrected
poses 4.5 cm RMS and 7.1 cm at worst from the truth with a prior of 2 cm and 1° on the odometry's
(reset) poses, 3.5 and 5.8 cm on the wheels, 2.5 and 3.5 cm with this prior, 1.2 and 2.1 cm anchored.

Measured on two five-minute three-room runs of the simulator (``invent up --goal-file``, the left
wheel's odometry 1 % off, lidar noise σ = 0.01 m, no localization fixes) and on benchmarks/mapping.py's
synthetic run: occupied cells within 10 cm of a wall 100 % (the odometry alone: 22 %), about 10 ms a
scan (12 ms with the normals fitted per side). A correlative grid search around the prior before the refinement (Olson's, ±0.1 m, ±3°) was
measured worse (87 to 88 %) and slower; matching to cell centres, without facings or sides, 87 to 94 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from services.mapping.occupancy import FACINGS, LogOddsGrid, dominant_facing
from services.navigation.grid import GridGeometry
from services.planar import Pose, wrap_angle

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Indices = npt.NDArray[np.intp]


@dataclass(frozen=True)
class MatcherSettings:
    """How far and how finely a match searches, and what it takes to trust one."""

    max_distance: float = 0.25
    """m: the distance field's clip; a point this far from every occupied cell is an outlier."""
    point_sigma: float = 0.03
    """m: how far a point lies from the map's surface, typically (the noise, half a cell)."""
    prior_xy_sigma: float = 0.005
    """m: how far the prior may be off along each axis, typically: a direction the scan does not
    constrain (a doorway, a corridor) keeps the prior's value rather than the noise's. The wheels'
    motion over the 0.1 s between two scans is good to a fraction of a millimetre (1 % of 3 cm); a
    looser prior lets each scan's match walk by the map's own small biases, which add up at every door
    (the three_rooms tour: 2 cm and 1° gave 6.1 cm in room 3, these 2.5 cm)."""
    prior_theta_sigma: float = math.radians(0.3)
    iterations: int = 12
    """Gauss–Newton steps at most."""
    min_inliers: float = 0.3
    """Share of the points that must lie within ``max_distance`` of the map for a match to count."""
    min_points: int = 20
    """A scan with fewer points than this is not matched."""


@dataclass(frozen=True)
class Match:
    """A match's result: the pose and how well the points fit there."""

    pose: Pose
    inliers: float
    """Share of the points within ``max_distance`` of an occupied cell."""
    rms: float
    """m: the inliers' root-mean-square distance."""

    def trusted(self, settings: MatcherSettings) -> bool:
        return self.inliers >= settings.min_inliers


@dataclass(frozen=True, eq=False)
class SurfaceField:
    """What a scan is matched against, over the window of a map around a prior: for each facing, the
    distance from each cell to the nearest occupied cell of that facing (m, clipped at
    ``max_distance``) and which cell that is; and each occupied cell's surface point (the mean of
    its hits, finer than the cell) and, where its neighbours' surface points lie on a line, that
    line's normal. Arrays are indexed ``[facing, row, col]`` or by flat cell of ``geometry``."""

    geometry: GridGeometry
    max_distance: float
    distances: Floats
    nearest: Indices
    surface: Floats
    """``[cell, 2]``: each cell's surface point in ``map``."""
    normals: Floats
    """``[cell, 2]``: each cell's surface normal, (0, 0) where its neighbours make no line."""
    sides: Floats
    """``[cell, 2]``: a direction towards the side each cell's surface was seen from."""

    @classmethod
    def around(cls, grid: LogOddsGrid, x: float, y: float, radius: float, max_distance: float) -> SurfaceField | None:
        """The field of ``grid``'s window within ``radius`` (plus ``max_distance``) of (x, y); None when
        the window holds no occupied cell."""
        geometry = grid.geometry
        resolution = geometry.resolution
        reach = math.ceil((radius + max_distance) / resolution) + 1
        col, row = math.floor((x - geometry.origin_x) / resolution), math.floor((y - geometry.origin_y) / resolution)
        c0, c1 = max(col - reach, 0), min(col + reach + 1, geometry.width)
        r0, r1 = max(row - reach, 0), min(row + reach + 1, geometry.height)
        if c0 >= c1 or r0 >= r1:
            return None
        occupied = grid.occupied()[r0:r1, c0:c1]
        if not occupied.any():
            return None
        window = GridGeometry(
            resolution, c1 - c0, r1 - r0, geometry.origin_x + c0 * resolution, geometry.origin_y + r0 * resolution
        )
        facing = grid.facing[r0:r1, c0:c1]
        distances = np.full((FACINGS, *occupied.shape), max_distance)
        nearest = np.zeros((FACINGS, *occupied.shape), dtype=np.intp)
        for bit in range(FACINGS):
            surface = occupied & (facing & (1 << bit) != 0)
            if surface.any():
                found, (rows, cols) = ndimage.distance_transform_edt(~surface, return_indices=True)
                distances[bit] = np.minimum(found * resolution, max_distance)
                nearest[bit] = rows * window.width + cols
        # surface points relative to the window's lower-left corner: small numbers for the moments
        counts = np.maximum(grid.hit_counts[r0:r1, c0:c1], 1.0)
        sx = (np.arange(window.width)[None, :] + 0.5) * resolution + grid.hit_sums[r0:r1, c0:c1, 0] / counts
        sy = (np.arange(window.height)[:, None] + 0.5) * resolution + grid.hit_sums[r0:r1, c0:c1, 1] / counts
        view_cells = grid.view_sums[r0:r1, c0:c1]
        view = view_cells.reshape(-1, 2)
        normals = _normals(occupied, sx, sy, view_cells, resolution)
        # turned to the side the surface was seen from; where no line, that side's mean direction
        sides = np.where((np.sum(normals * view, axis=1) < 0.0)[:, None], -normals, normals)
        no_line = ~normals.any(axis=1)
        sides[no_line] = view[no_line]
        surface = np.stack((sx + window.origin_x, sy + window.origin_y), axis=-1).reshape(-1, 2)
        return cls(window, max_distance, distances, nearest, surface, normals, sides)


NORMAL_NEIGHBOURHOOD = 7
"""Cells a side of the square of neighbours whose surface points give a cell's surface line."""
MIN_LINE_CELLS = 4
"""Occupied cells a neighbourhood needs to make a line."""
MIN_LINE_SPREAD = 0.8
"""Cells: the least standard deviation along a line (a few cells' clump of a far, grazed wall is no line)."""
LINE_FLATNESS = 0.1
"""A neighbourhood is a line where its points' variance across is at most this share of along."""


def _normals(occupied: Bools, sx: Floats, sy: Floats, view: Floats, resolution: float) -> Floats:
    """``[cell, 2]``: the normal of the line through each occupied cell's neighbours' surface points
    (``sx``, ``sy``), (0, 0) where they are too few or make no line (a corner, an end) and off the
    occupied cells. Only neighbours seen from the cell's side count: the cells are fitted in four
    groups, those seen from +x, −x, +y, −y (by the sign of their ``view``, ``[row, col, 2]``; a cell
    is in two), and each takes its flatter group's line. A thin wall's two faces lie within one
    neighbourhood (a wall of 0.1 m: two cells apart): fitted together they make no line, and a point
    on one face would then match the other's surface points, a wall's thickness away."""
    size = NORMAL_NEIGHBOURHOOD**2
    cells = np.flatnonzero(occupied)
    best = np.full(len(cells), np.inf)
    major = np.zeros(len(cells))
    flat_view = view.reshape(-1, 2)[cells]
    for axis, sign in ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)):
        member = occupied & (sign * view[:, :, axis] > 0.0)
        in_group = sign * flat_view[:, axis] > 0.0
        if not in_group.any():
            continue
        weight = member.astype(np.float64)
        at = member[occupied]

        def summed(values: Floats, weight: Floats = weight, at: Bools = at) -> Floats:
            # a box filter (separable: cheaper than a correlation), read at the group's cells only
            return ndimage.uniform_filter(values * weight, NORMAL_NEIGHBOURHOOD, mode="constant")[occupied][at] * size

        count = np.rint(summed(np.ones_like(sx)))  # >= 1: the cell itself
        mx, my = summed(sx) / count, summed(sy) / count
        cxx = summed(sx * sx) / count - mx * mx
        cxy = summed(sx * sy) / count - mx * my
        cyy = summed(sy * sy) / count - my * my
        half_sum, half_difference = (cxx + cyy) / 2, (cxx - cyy) / 2
        spread = np.sqrt(half_difference**2 + cxy**2)
        along, across = half_sum + spread, half_sum - spread
        is_line = (
            (count >= MIN_LINE_CELLS)
            & (across <= LINE_FLATNESS * along)
            & (along >= (MIN_LINE_SPREAD * resolution) ** 2)
        )
        flatness = np.where(is_line, across / np.maximum(along, 1e-18), np.inf)
        better = flatness < best[at]
        index = np.flatnonzero(at)[better]
        best[index] = flatness[better]
        major[index] = 0.5 * np.arctan2(2 * cxy[better], (cxx - cyy)[better])
    normals = np.zeros((occupied.size, 2))
    line = np.isfinite(best)
    normals[cells[line]] = np.stack((-np.sin(major[line]), np.cos(major[line])), axis=-1)
    return normals


def transform(pose: Pose, points: Floats) -> tuple[Floats, Floats]:
    """``points`` (``[n, 2]`` in the robot's frame) in the map frame at ``pose``."""
    cos, sin = math.cos(pose.theta), math.sin(pose.theta)
    px, py = points[:, 0], points[:, 1]
    return pose.x + cos * px - sin * py, pose.y + sin * px + cos * py


def match(
    points: Floats, lidar: tuple[float, float], prior: Pose, field: SurfaceField, settings: MatcherSettings
) -> Match:
    """The pose near ``prior`` at which ``points`` (``[n, 2]``, robot frame, seen from ``lidar`` there)
    best fit ``field``."""
    angle = prior.theta
    dx, dy = points[:, 0] - lidar[0], points[:, 1] - lidar[1]
    facings = dominant_facing(math.cos(angle) * dx - math.sin(angle) * dy, math.sin(angle) * dx + math.cos(angle) * dy)
    return _refine(points, lidar, facings, prior, field, settings)


def _refine(
    points: Floats,
    lidar: tuple[float, float],
    facings: Indices,
    prior: Pose,
    field: SurfaceField,
    settings: MatcherSettings,
) -> Match:
    """Gauss–Newton from ``prior`` on the points' distances to their nearest surfaces (along the
    surface's normal: point-to-line; point-to-point where the surface makes no line), robustly
    weighed, and on the distance to ``prior``."""
    pose = prior
    px, py = points[:, 0], points[:, 1]
    prior_weights = settings.point_sigma**2 * np.diag(
        [settings.prior_xy_sigma**-2, settings.prior_xy_sigma**-2, settings.prior_theta_sigma**-2]
    )
    for _ in range(settings.iterations):
        valid, residual, normals = _residuals(pose, points, lidar, facings, field)
        if np.count_nonzero(valid) < 3:
            break
        cos, sin = math.cos(pose.theta), math.sin(pose.theta)
        turn_x, turn_y = (-sin * px - cos * py)[valid], (cos * px - sin * py)[valid]
        jacobian = np.stack((normals[:, 0], normals[:, 1], normals[:, 0] * turn_x + normals[:, 1] * turn_y), axis=1)
        # Cauchy's weights: a point far off its surface (something new, a wrong neighbour) counts little
        weights = 1.0 / (1.0 + (residual / settings.point_sigma) ** 2)
        offset = np.array([pose.x - prior.x, pose.y - prior.y, wrap_angle(pose.theta - prior.theta)])
        hessian = jacobian.T @ (weights[:, None] * jacobian) + prior_weights
        step = -np.linalg.solve(hessian, jacobian.T @ (weights * residual) + prior_weights @ offset)
        pose = Pose(pose.x + float(step[0]), pose.y + float(step[1]), pose.theta + float(step[2]))
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    valid, residual, _ = _residuals(pose, points, lidar, facings, field)
    count = int(np.count_nonzero(valid))
    rms = math.sqrt(float(np.mean(np.square(residual)))) if count else math.inf
    return Match(Pose(pose.x, pose.y, wrap_angle(pose.theta)), count / max(len(points), 1), rms)


def _residuals(
    pose: Pose, points: Floats, lidar: tuple[float, float], facings: Indices, field: SurfaceField
) -> tuple[Bools, Floats, Floats]:
    """``(valid, residual, normal)``: which points have a surface of their facing within
    ``max_distance`` seen from the lidar's side, and for those, their signed distance along the
    normal used and that normal."""
    x, y = transform(pose, points)
    (lidar_x,), (lidar_y,) = transform(pose, np.array([lidar]))
    geometry = field.geometry
    cols, rows, on = geometry.cells_of(x, y)
    valid = on & (field.distances[facings, rows, cols] < field.max_distance)
    cells = field.nearest[facings[valid], rows[valid], cols[valid]]
    sides = field.sides[cells]
    same_side = sides[:, 0] * (lidar_x - x[valid]) + sides[:, 1] * (lidar_y - y[valid]) > 0.0
    # only where the surface makes a line: a corner's or an end's surface point is the mean of the hits
    # it took from where it was seen so far, and a point-to-point match to it pulls the pose back there
    same_side &= field.normals[cells].any(axis=1)
    valid[valid] = same_side
    cells = cells[same_side]
    ex, ey = x[valid] - field.surface[cells, 0], y[valid] - field.surface[cells, 1]
    normals = field.normals[cells]
    return valid, normals[:, 0] * ex + normals[:, 1] * ey, normals
