"""The global planner (pure; docs/navigation.md): a path on the costmap from the robot to a goal, or the
reason there is none.

**Search** (:func:`route`). A grid search on :attr:`Costmap.costs`, 8-connected, for the cheapest path
where a step costs its length × (1 + cost_weight · cost/252) of the cell it enters, so that a plan
keeps its distance from obstacles where it can and cuts close where it must. A step never enters an
``INSCRIBED`` or ``LETHAL`` cell, and a diagonal step never cuts a corner of one (both cells beside it
must be enterable too), with one exception: from a start cell that is ``INSCRIBED`` or ``LETHAL`` (a
robot pushed close to something, lidar noise on its own cell) the path may cross ``INSCRIBED`` cells
along a contiguous prefix, so that it can leave; once on a cell below ``INSCRIBED`` it never enters one
again. Every result is deterministic: the same costs and ends give the same path, bit for bit.

The search is pyastar2d's (a compiled A*), chosen by measurement over the exact pure Python A*
(:func:`search`; benchmarks/README.md, "Navigation"): 30 to 40 times faster across a 20 × 20 m
building of rooms (7 ms against 240 to 280; the whole plan, smoothed, about 11 ms), 5 to 8 times on
emptier costmaps, and, once both are smoothed alike, plans that cost what the exact search's do (on
random maps the median difference 0 %, within 5 % either way in 85 plans of 100, at worst 28 % more).
pyastar2d takes a weight per cell (here the step's multiplier above; ``inf`` where the robot may not
go) and charges a diagonal step the weight of the cell it enters, as a straight one (no √2): its grid
path is the cheapest in that measure, not exactly in the one above. A popped cell may come up again
from a stale queue entry (its relaxations then change nothing). What it does not know is done around
it:

- the **escape**: from a start the body already touches, :func:`search` (its expansions bounded to
  the cells the body touches) finds the way out to the first cell below ``INSCRIBED`` in the goal's
  region (lowest cost so far plus the octile distance left), and pyastar2d goes on from there;
- **regions**: where the start (or the escape's end) and the goal lie in different 4-connected regions
  of enterable cells (what a path that cuts no corner can join), there is no path, found at once;
- **corners**: a diagonal step of pyastar2d's past one blocked cell goes round it through the other,
  enterable one; a step squeezed between two (none in 196 random plans: it happens only where two
  inflated obstacles touch at a corner) hands the whole search to :func:`search`.

**Smoothing** (:func:`smooth`). The grid path (the start, the centres of the cells between, the goal)
is pulled taut: a run of points is replaced by the straight segment between its ends only if the
highest cost of the cells the segment crosses is no higher than the highest cost of the cells the
run's own segments cross (both counted as :meth:`Costmap.line_cost` counts them, a cell touched at a
corner included), so smoothing never brings the path closer to an obstacle than the grid path was.
From each point the farthest such end is found by galloping (2, 4, 8, ... points on) then bisecting:
a handful of line checks instead of one per point. The escape prefix is kept as searched.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pyastar2d
from scipy import ndimage

from services.navigation.costmap import INSCRIBED, LETHAL, MAX_INFLATED, Costmap, describe_extent

Bools = npt.NDArray[np.bool_]

SQRT2 = math.sqrt(2.0)
DIAGONAL_SAVING = SQRT2 - 2.0
"""The octile distance is rows + cols + this × min(rows, cols): a diagonal step for two straight ones."""


@dataclass(frozen=True)
class Plan:
    """A path in ``map``: ``points`` from the start (exactly) to the goal (exactly), at least two, and
    its ``length`` (m) along them."""

    points: tuple[tuple[float, float], ...]
    length: float


@dataclass(frozen=True)
class NoPlan:
    """Why there is no path (the coordinates named with 2 decimals)."""

    reason: str


def plan_path(
    costmap: Costmap, start: tuple[float, float], goal: tuple[float, float], cost_weight: float
) -> Plan | NoPlan:
    """The cheapest path from ``start`` to ``goal`` (both in ``map``) on ``costmap``, smoothed, or why
    there is none: the robot or the goal off the costmap, the goal in an obstacle or within the
    inscribed radius of one, or every way blocked."""
    if not (math.isfinite(cost_weight) and cost_weight >= 0.0):
        raise ValueError(f"cost_weight {cost_weight!r} must be finite and >= 0")
    geometry = costmap.geometry
    sx, sy = start
    gx, gy = goal
    start_cell = geometry.cell(sx, sy)
    if start_cell is None:
        return NoPlan(f"the robot ({sx:.2f}, {sy:.2f}) is off the costmap (extent {describe_extent(geometry)})")
    goal_cell = geometry.cell(gx, gy)
    if goal_cell is None:
        return NoPlan(f"the goal ({gx:.2f}, {gy:.2f}) is off the costmap (extent {describe_extent(geometry)})")
    costs = costmap.costs
    goal_cost = int(costs[goal_cell[1], goal_cell[0]])
    if goal_cost >= LETHAL:
        return NoPlan(f"the goal ({gx:.2f}, {gy:.2f}) is in an obstacle")
    if goal_cost >= INSCRIBED:
        return NoPlan(
            f"the goal ({gx:.2f}, {gy:.2f}) is within {costmap.inscribed_radius:.2f} m of an obstacle: "
            "the robot cannot stand there"
        )
    width = geometry.width
    cells = route(costs, start_cell[1] * width + start_cell[0], goal_cell[1] * width + goal_cell[0], cost_weight)
    if cells is None:
        return NoPlan(f"no path from ({sx:.2f}, {sy:.2f}) to ({gx:.2f}, {gy:.2f}): every way is blocked")
    points = smooth(costmap, cells, (float(sx), float(sy)), (float(gx), float(gy)))
    length = math.fsum(math.dist(a, b) for a, b in itertools.pairwise(points))
    return Plan(points, length)


def route(costs: npt.NDArray[np.uint8], start: int, goal: int, cost_weight: float) -> list[int] | None:
    """The grid path from cell ``start`` to cell ``goal`` (flat indices ``row * width + col`` of ``costs``),
    both ends included, by the rules above; None if every way is blocked. The goal's cell must be below
    ``INSCRIBED`` (:func:`plan_path` says why not otherwise)."""
    width = costs.shape[1]
    flat = costs.reshape(-1)
    enterable = costs < INSCRIBED
    regions, _ = ndimage.label(enterable)  # 4-connected: what paths that cut no corner can join
    region = regions.reshape(-1)
    goal_region = region[goal]
    prefix = [start]
    if flat[start] >= INSCRIBED:
        escape = search(costs, start, goal, cost_weight, exits=region == goal_region)
        if escape is None:
            return None
        prefix = escape
    elif region[start] != goal_region:
        return None
    origin = prefix[-1]
    weights = np.where(enterable, 1.0 + (cost_weight / MAX_INFLATED) * costs, np.inf).astype(np.float32)
    found = pyastar2d.astar_path(weights, divmod(origin, width), divmod(goal, width), allow_diagonal=True)
    if found is None:  # the same region: never, but say so rather than fail
        return None
    path = (found[:, 0] * width + found[:, 1]).tolist()
    # pyastar2d may leave its start out (seen: a start reached again from a cell of the same cost): the
    # exact search then, as for a path that squeezes between blocked cells
    cells = _round_corners(enterable, path, width) if path[0] == origin else None
    if cells is None:
        cells = search(costs, origin, goal, cost_weight)
        if cells is None:
            return None
    return _without_loops(prefix[:-1] + cells)


def _without_loops(cells: list[int]) -> list[int]:
    """The path with every loop cut out: a cell met again (a corner taken round onto a cell the path
    visits next anyway) continues from its first visit, so each cell comes once and steps stay steps."""
    out: list[int] = []
    at: dict[int, int] = {}
    for cell in cells:
        if cell in at:
            del out[at[cell] + 1 :]
            at = {kept: index for index, kept in enumerate(out)}
            continue
        at[cell] = len(out)
        out.append(cell)
    return out


def _round_corners(enterable: npt.NDArray[np.bool_], cells: list[int], width: int) -> list[int] | None:
    """The path with each diagonal step past a blocked cell taken round it through the cell on its other
    side; None if a step squeezes between two blocked cells."""
    passable = enterable.reshape(-1)
    out = [cells[0]]
    for before, cell in itertools.pairwise(cells):
        row, col = divmod(before, width)
        next_row, next_col = divmod(cell, width)
        if row != next_row and col != next_col:
            side_a, side_b = row * width + next_col, next_row * width + col
            if not passable[side_a]:
                if not passable[side_b]:
                    return None
                out.append(side_b)
            elif not passable[side_b]:
                out.append(side_a)
        out.append(cell)
    return out


def search(
    costs: npt.NDArray[np.uint8],
    start: int,
    goal: int,
    cost_weight: float,
    exits: npt.NDArray[np.bool_] | None = None,
) -> list[int] | None:
    """Pure Python A* (heapq) from cell ``start`` to cell ``goal`` (flat indices ``row * width + col`` of
    ``costs``) by the rules above, exactly: the cells of the cheapest path, both ends included; None if
    every way is blocked. The heuristic is the octile distance, admissible and consistent since a step
    never costs less than its length; with a closed set every cell is expanded at most once; ties go
    to the smaller heuristic, then the smaller cell index.

    ``exits`` (a flag per cell, flat): stop at the first cell below ``INSCRIBED`` reached that is one
    (the lowest cost so far plus the octile distance to ``goal``), never going on from a cell below
    ``INSCRIBED`` that is not: the way out of the cells the body touches, from a start among them."""
    height, width = costs.shape
    stride = width + 2
    padded = np.full((height + 2, stride), LETHAL, dtype=np.uint8)
    padded[1:-1, 1:-1] = costs
    multiplier = 1.0 + (cost_weight / MAX_INFLATED) * padded.astype(np.float64)
    # a step's cost per unit length into each cell: infinite where it may not go
    normal: list[float] = np.where(padded < INSCRIBED, multiplier, math.inf).ravel().tolist()
    origin = (start // width + 1) * stride + start % width + 1
    target = (goal // width + 1) * stride + goal % width + 1
    # from a cell the body already touches (the start, or the INSCRIBED cells escaped through from it)
    escape = (
        np.where(padded <= INSCRIBED, multiplier, math.inf).ravel().tolist() if normal[origin] == math.inf else normal
    )
    moves = (
        (1, 1.0, 0, 0),
        (-1, 1.0, 0, 0),
        (stride, 1.0, 0, 0),
        (-stride, 1.0, 0, 0),
        (stride + 1, SQRT2, stride, 1),
        (stride - 1, SQRT2, stride, -1),
        (-stride + 1, SQRT2, -stride, 1),
        (-stride - 1, SQRT2, -stride, -1),
    )
    inf = math.inf
    target_row, target_col = divmod(target, stride)
    best = [inf] * (stride * (height + 2))
    parent: dict[int, int] = {}
    closed = bytearray(stride * (height + 2))
    stop: bytearray | None = None
    if exits is not None:
        stop = bytearray(stride * (height + 2))
        np.frombuffer(stop, dtype=np.uint8).reshape(height + 2, stride)[1:-1, 1:-1] = exits.reshape(height, width)
    best[origin] = 0.0
    heuristic = _octile(origin, target_row, target_col, stride)
    frontier: list[tuple[float, float, int]] = [(heuristic, heuristic, origin)]
    pop, push, divide = heapq.heappop, heapq.heappush, divmod
    while frontier:
        _, _, cell = pop(frontier)
        if closed[cell]:
            continue
        if cell == target:
            break
        closed[cell] = 1
        if stop is not None and normal[cell] != inf and cell != origin:
            if stop[cell]:
                target = cell
                break
            continue  # out, but away from the goal's region: a dead end
        so_far = best[cell]
        step_costs = normal if normal[cell] != inf else escape
        for offset, length, side_a, side_b in moves:
            neighbour = cell + offset
            cost = so_far + length * step_costs[neighbour]
            if cost < best[neighbour]:
                if side_a and (step_costs[cell + side_a] == inf or step_costs[cell + side_b] == inf):
                    continue  # a corner of a cell it may not enter
                if closed[neighbour]:
                    continue
                best[neighbour] = cost
                parent[neighbour] = cell
                row, col = divide(neighbour, stride)
                rows, cols = abs(row - target_row), abs(col - target_col)
                heuristic = rows + cols + DIAGONAL_SAVING * (rows if rows < cols else cols)  # noqa: FURB136 (no call)
                push(frontier, (cost + heuristic, heuristic, neighbour))
    else:
        return None
    path = [target]
    while path[-1] != origin:
        path.append(parent[path[-1]])
    path.reverse()
    return [(cell // stride - 1) * width + cell % stride - 1 for cell in path]


def _octile(cell: int, target_row: int, target_col: int, stride: int) -> float:
    row, col = divmod(cell, stride)
    rows, cols = abs(row - target_row), abs(col - target_col)
    return rows + cols + DIAGONAL_SAVING * min(rows, cols)


def smooth(
    costmap: Costmap, cells: list[int], start: tuple[float, float], goal: tuple[float, float]
) -> tuple[tuple[float, float], ...]:
    """The grid path ``cells`` (flat indices, start to goal) as points, pulled taut: the start, the
    cells' centres, the goal, with runs replaced by straight segments, each crossing no cell costlier
    than the costliest the run's own segments cross (both counted as :meth:`Costmap.line_cost` counts,
    a cell touched at a corner included); the escape prefix (the INSCRIBED cells from the start) kept.

    From each point kept, the segments to the points 2, 4, 8, ... on are checked at once (galloping)
    up to the first that does not hold; between the last that holds and it, up to 8 evenly spaced ends
    at once, narrowing to two neighbours; the farthest that holds there is the next point kept."""
    geometry = costmap.geometry
    width = geometry.width
    last = len(cells) - 1
    if last == 0:
        return (start, goal)
    points = [start, *(geometry.centre(cell % width, cell // width) for cell in cells[1:last]), goal]
    xs = np.array([x for x, _ in points], dtype=np.float64)
    ys = np.array([y for _, y in points], dtype=np.float64)
    step_costs = costmap.line_costs(xs[:-1], ys[:-1], xs[1:], ys[1:])
    path_costs = costmap.costs.reshape(-1)[np.array(cells, dtype=np.intp)]
    anchor = 0
    while anchor < last and path_costs[anchor] >= INSCRIBED:
        anchor += 1
    kept = points[: anchor + 1]
    while anchor < last:
        bound = np.maximum.accumulate(step_costs[anchor:])  # a segment to point j: bound[j - anchor - 1]

        def holds(ends: npt.NDArray[np.intp], anchor: int = anchor, bound: npt.NDArray[np.uint8] = bound) -> Bools:
            count = ends.shape[0]
            worst = costmap.line_costs(np.full(count, xs[anchor]), np.full(count, ys[anchor]), xs[ends], ys[ends])
            # never into a cell where the body touches: the grid path's diagonal steps may graze the
            # corner of one (a corner touched counts), which must not license a shortcut through it
            return worst <= np.minimum(bound[ends - anchor - 1], INSCRIBED - 1)

        low, high = anchor + 1, last + 1  # the segment to low holds (the grid path's own step)
        probes = np.unique(np.minimum(anchor + (2 << np.arange(max(last - anchor, 1).bit_length())), last))
        probes = probes[probes > low]
        while probes.size:
            failing = np.flatnonzero(~holds(probes))
            if failing.size == 0:
                low = int(probes[-1])
            else:
                first = int(failing[0])
                low, high = (int(probes[first - 1]) if first else low), int(probes[first])
            probes = np.unique(np.linspace(low, high, 10).astype(np.intp))
            probes = probes[(probes > low) & (probes < high)]
        anchor = low
        kept.append(points[anchor])
    return tuple(kept)
