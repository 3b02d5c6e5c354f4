"""The ``navigation`` section of ``make bench``: what the drive's navigation costs in its own thread,
which the whole lockstep simulation waits on (benchmarks/README.md, "Navigation").

- **Costmap update per scan**: :meth:`Costmap.mark_scan` and the lazy inflation it causes (the next
  read of :attr:`Costmap.costs`), the default lidar (360 rays, 3.5 m) on the default costmap (20 × 20 m
  at 5 cm), the robot driving through a building of rooms with doors (3 × 3 rooms, each wall with a
  door of 1.8 m), its scans cast in that building beforehand (not timed). Without a map (the lidar's
  obstacle layer alone: each scan marks walls it had not seen) and with the building as the map.
- **Plan**: :func:`plan_path` from one corner room of the building to the opposite one (its search,
  pyastar2d's, and its smoothing apart), the robot of the default radius, on three costmaps: the
  building as the map; no map, the walls the lidar saw driving across; no obstacles. Beside it the
  exact pure Python A* (:func:`search`) on the same costs: the alternative measured against pyastar2d.
- **Quality**: on random obstacle maps, what the plans of pyastar2d's search cost against those of the
  exact A*, both smoothed alike (the integral of 1 + cost_weight · cost/252 along the plan, what the
  planner minimises), and their lengths: what choosing pyastar2d gives up.

Each figure is in ms of wall time and as a share of the lidar's period (0.1 s at 10 Hz): the share of
each scan's time the drive's thread spends on it.
"""

from __future__ import annotations

import argparse
import itertools
import math
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from benchmarks.figures import fmt, timed
from schemas.messages import LaserScan, Time
from services.config import RobotConfig
from services.config.navigation import NavigationConfig
from services.config.sensors import LidarConfig
from services.navigation import planner
from services.navigation.costmap import INSCRIBED, MAX_INFLATED, Costmap
from services.navigation.grid import FREE, OCCUPIED, GridGeometry, Occupancy
from services.navigation.planner import Plan, plan_path, search, smooth

SIZE = 20.0
"""m: the side of the building and of the costmap (the default ``navigation.size``)."""
ROOMS = 3
"""Rooms along each side."""
WALL = 0.1
"""m: a wall's thickness."""
DOOR = 1.8
"""m: each interior wall's door."""
START = (-8.0, -8.0)
GOAL = (8.0, 8.0)
"""The plan's ends: the centres of opposite corner rooms (about 6.67 m apart room to room)."""
ROUTE_SPACING = 0.1
"""m between the robot's poses along its route (a scan at each: 1 m/s at 10 Hz)."""


def building(geometry: GridGeometry) -> Occupancy:
    """The building: outer walls, ``ROOMS`` × ``ROOMS`` rooms, a door in each interior wall, the doors of
    successive walls at alternating ends so that a way across winds."""
    cells = np.full(geometry.shape, FREE, dtype=np.int8)
    xs = geometry.origin_x + (np.arange(geometry.width) + 0.5) * geometry.resolution
    ys = geometry.origin_y + (np.arange(geometry.height) + 0.5) * geometry.resolution
    low, high = geometry.origin_x + WALL, geometry.max_x - WALL
    room = (high - low) / ROOMS
    near_x = (xs < low) | (xs > high)
    near_y = (ys < low) | (ys > high)
    cells[:, near_x] = OCCUPIED
    cells[near_y, :] = OCCUPIED
    for wall in range(1, ROOMS):
        at = low + wall * room
        in_wall_x = np.abs(xs - at) < WALL / 2
        in_wall_y = np.abs(ys - at) < WALL / 2
        for span in range(ROOMS):
            start = low + span * room
            # the door sits near one end of the span, alternating with the wall and the span
            door_at = start + (0.25 if (wall + span) % 2 else 0.75) * room
            door_x = np.abs(xs - door_at) < DOOR / 2
            door_y = np.abs(ys - door_at) < DOOR / 2
            span_x = (xs >= start) & (xs < start + room)
            span_y = (ys >= start) & (ys < start + room)
            cells[np.ix_(span_y & ~door_y, in_wall_x)] = OCCUPIED  # a wall of constant x
            cells[np.ix_(in_wall_y, span_x & ~door_x)] = OCCUPIED  # a wall of constant y
    return cells


def cast_scan(
    occupied: npt.NDArray[np.bool_], geometry: GridGeometry, x: float, y: float, lidar: LidarConfig
) -> LaserScan:
    """The default lidar's scan from (``x``, ``y``), heading 0, in the occupancy ``occupied``: each ray
    sampled every quarter cell up to ``range_max``, its range the first occupied sample's."""
    angles = lidar.angle_min + lidar.angle_increment * np.arange(lidar.rays)
    distances = np.arange(lidar.range_min, lidar.range_max, geometry.resolution / 4.0)
    px = x + np.cos(angles)[:, None] * distances[None, :]
    py = y + np.sin(angles)[:, None] * distances[None, :]
    cols, rows, on_grid = geometry.cells_of(px, py)
    hit = occupied[rows, cols] | ~on_grid
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
    ranges = [float(distances[index]) if index >= 0 else None for index in first]
    return LaserScan(
        tm=Time(sec=0, nsec=0),
        angle_min=lidar.angle_min,
        angle_increment=lidar.angle_increment,
        range_min=lidar.range_min,
        range_max=lidar.range_max,
        ranges=ranges,
    )


def poses_along(plan: Plan, spacing: float) -> list[tuple[float, float]]:
    """Points every ``spacing`` m along a plan."""
    points: list[tuple[float, float]] = []
    for (x0, y0), (x1, y1) in itertools.pairwise(plan.points):
        steps = max(1, math.ceil(math.dist((x0, y0), (x1, y1)) / spacing))
        points += [(x0 + (x1 - x0) * k / steps, y0 + (y1 - y0) * k / steps) for k in range(steps)]
    return [*points, plan.points[-1]]


def _setting() -> tuple[GridGeometry, NavigationConfig, float, Occupancy]:
    settings = NavigationConfig()
    geometry = GridGeometry.centred(0.0, 0.0, SIZE, settings.resolution)
    return geometry, settings, RobotConfig().radius_of_body_area, building(geometry)


def costmap_updates(scans: int) -> dict[str, Any]:
    """ms per scan (mark + inflation) along the route across the building, without and with a map."""
    geometry, settings, radius, walls = _setting()
    lidar = LidarConfig()
    mapped = Costmap(geometry, settings, radius, walls)
    plan = plan_path(mapped, START, GOAL, settings.cost_weight)
    assert isinstance(plan, Plan), plan
    poses = poses_along(plan, ROUTE_SPACING)[:scans]
    occupied = walls == OCCUPIED
    sweeps = [cast_scan(occupied, geometry, x, y, lidar) for x, y in poses]
    results: dict[str, Any] = {"scans": len(sweeps), "rays": lidar.rays, "range_max": lidar.range_max}
    for name, static in (("no_map", None), ("map", walls)):
        costmap = Costmap(geometry, settings, radius, static)
        _ = costmap.costs  # the first, whole inflation is the start-up's, not a scan's
        initial = costmap.status()
        mark_ms, inflate_ms, total_ms = [], [], []
        for (x, y), scan in zip(poses, sweeps, strict=True):
            started = time.perf_counter()
            costmap.mark_scan(scan, x, y, 0.0)
            marked = time.perf_counter()
            _ = costmap.costs
            ended = time.perf_counter()
            mark_ms.append((marked - started) * 1e3)
            inflate_ms.append((ended - marked) * 1e3)
            total_ms.append((ended - started) * 1e3)
        status = costmap.status()
        results[name] = {
            "ms": statistics.median(total_ms),
            "p95_ms": _percentile(total_ms, 95),
            "max_ms": max(total_ms),
            "mark_ms": statistics.median(mark_ms),
            "inflate_ms": statistics.median(inflate_ms),
            "inflations": status["inflations"] - initial["inflations"],
            "inflated_cells_per_inflation": (status["inflated_cells"] - initial["inflated_cells"])
            / max(status["inflations"] - initial["inflations"], 1),
            "scans_changing": status["scans_changing"],
        }
    return results


def _scenarios() -> dict[str, Costmap]:
    """The costmaps plans are timed on: the building as the map; no map, the walls the lidar saw on the
    way across (the drive's default, ``navigation.map = "none"``, once it has driven the route); open."""
    geometry, settings, radius, walls = _setting()
    mapped = Costmap(geometry, settings, radius, walls)
    plan = plan_path(mapped, START, GOAL, settings.cost_weight)
    assert isinstance(plan, Plan), plan
    seen = Costmap(geometry, settings, radius)
    lidar, occupied = LidarConfig(), walls == OCCUPIED
    for x, y in poses_along(plan, ROUTE_SPACING):
        seen.mark_scan(cast_scan(occupied, geometry, x, y, lidar), x, y, 0.0)
    return {"building": mapped, "seen": seen, "open": Costmap(geometry, settings, radius)}


def plans(repeats: int) -> dict[str, Any]:
    """ms per plan from ``START`` to ``GOAL`` on each scenario: the whole plan, its search (pyastar2d's,
    with what the planner does around it) and its smoothing; the exact A* on the same costs."""
    weight = NavigationConfig().cost_weight
    results: dict[str, Any] = {}
    for name, costmap in _scenarios().items():
        costs = costmap.costs
        start, goal = _flat(costmap, START), _flat(costmap, GOAL)
        plan = plan_path(costmap, START, GOAL, weight)
        assert isinstance(plan, Plan), plan
        cells, exact = planner.route(costs, start, goal, weight), search(costs, start, goal, weight)
        assert cells is not None and exact is not None
        results[name] = {
            "plan_ms": _median_ms(lambda costmap=costmap: plan_path(costmap, START, GOAL, weight), repeats),
            "route_ms": _median_ms(lambda c=costs, a=start, b=goal: planner.route(c, a, b, weight), repeats),
            "smooth_ms": _median_ms(lambda costmap=costmap, cells=cells: smooth(costmap, cells, START, GOAL), repeats),
            "exact_search_ms": _median_ms(lambda c=costs, a=start, b=goal: search(c, a, b, weight), repeats),
            "length_m": plan.length,
            "points": len(plan.points),
            "grid_path_cells": len(cells),
            "grid_path_cost": path_cost(costs, cells, weight),
            "exact_grid_path_cost": path_cost(costs, exact, weight),
            "exact_length_m": _length(smooth(costmap, exact, START, GOAL)),
        }
    return results


def planner_quality(trials: int, seed: int = 1) -> dict[str, Any]:
    """The planner's plans (pyastar2d's search) against the exact A*'s on random obstacle maps (10 x 10 m
    at 5 cm, 12 random boxes, a body of 0.3 m, random ends below ``INSCRIBED``), both smoothed alike:
    how much more the planner's cost (the integral of 1 + cost_weight · cost/252 along the smoothed
    plan, what the planner minimises) and how much longer they are."""
    settings = NavigationConfig()
    weight = settings.cost_weight
    geometry = GridGeometry.centred(0.0, 0.0, 10.0, settings.resolution)
    generator = np.random.default_rng(seed)
    cost_ratios, length_ratios = [], []
    while len(cost_ratios) < trials:
        static = np.zeros(geometry.shape, dtype=np.int8)
        for _ in range(12):
            row, col = generator.integers(0, geometry.height), generator.integers(0, geometry.width)
            height, width = generator.integers(2, 60, size=2)
            static[row : row + height, col : col + width] = OCCUPIED
        costmap = Costmap(geometry, settings, 0.3, static)
        costs = costmap.costs
        free = np.flatnonzero(costs.reshape(-1) < INSCRIBED)
        if free.size < 2:
            continue
        start, goal = (int(cell) for cell in generator.choice(free, size=2, replace=False))
        ends = [geometry.centre(cell % geometry.width, cell // geometry.width) for cell in (start, goal)]
        exact, chosen = search(costs, start, goal, weight), planner.route(costs, start, goal, weight)
        if exact is None or chosen is None:
            continue
        ours, best = smooth(costmap, chosen, *ends), smooth(costmap, exact, *ends)
        cost_ratios.append(integral_cost(costmap, ours, weight) / integral_cost(costmap, best, weight))
        length_ratios.append(_length(ours) / max(_length(best), 1e-9))
    costs_more = np.array(cost_ratios) - 1.0
    longer = np.array(length_ratios) - 1.0
    return {
        "plans": trials,
        "cost_median": float(np.median(costs_more)),
        "cost_p10": float(np.percentile(costs_more, 10)),
        "cost_p90": float(np.percentile(costs_more, 90)),
        "cost_max": float(costs_more.max()),
        "cost_min": float(costs_more.min()),
        "share_costing_5_percent_more": float(np.mean(costs_more > 0.05)),
        "share_costing_20_percent_more": float(np.mean(costs_more > 0.20)),
        "share_costing_5_percent_less": float(np.mean(costs_more < -0.05)),
        "length_median": float(np.median(longer)),
        "length_p90": float(np.percentile(longer, 90)),
    }


def integral_cost(costmap: Costmap, points: tuple[tuple[float, float], ...], weight: float) -> float:
    """The integral of 1 + weight · cost/252 along a polyline (m), sampled every quarter cell."""
    total = 0.0
    step = costmap.geometry.resolution / 4.0
    flat = costmap.costs.reshape(-1)
    for (x0, y0), (x1, y1) in itertools.pairwise(points):
        length = math.dist((x0, y0), (x1, y1))
        count = max(1, math.ceil(length / step))
        t = (np.arange(count) + 0.5) / count
        cols, rows, _ = costmap.geometry.cells_of(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t)
        cost = flat[rows * costmap.geometry.width + cols].astype(np.float64)
        total += length * float(np.mean(1.0 + weight * cost / MAX_INFLATED))
    return total


def path_cost(costs: npt.NDArray[np.uint8], cells: list[int], weight: float) -> float:
    """A grid path's cost as the planner counts it (in cells): each step's length × (1 + weight · cost/252)
    of the cell it enters."""
    width = costs.shape[1]
    flat = costs.reshape(-1)
    total = 0.0
    for before, cell in itertools.pairwise(cells):
        diagonal = before % width != cell % width and before // width != cell // width
        total += (math.sqrt(2.0) if diagonal else 1.0) * (1.0 + weight * int(flat[cell]) / MAX_INFLATED)
    return total


def _flat(costmap: Costmap, point: tuple[float, float]) -> int:
    cell = costmap.geometry.cell(*point)
    assert cell is not None
    return cell[1] * costmap.geometry.width + cell[0]


def _length(points: tuple[tuple[float, float], ...]) -> float:
    return math.fsum(math.dist(a, b) for a, b in itertools.pairwise(points))


def _median_ms(action: Callable[[], object], repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        started = time.perf_counter()
        action()
        samples.append((time.perf_counter() - started) * 1e3)
    return statistics.median(samples)


def _percentile(values: list[float], percent: float) -> float:
    return float(np.percentile(np.array(values), percent))


def run_section(args: argparse.Namespace, failures: list[str]) -> dict[str, Any]:
    """The section's figures (``--quick``: a few scans, plans and comparisons)."""
    print("navigation", flush=True)
    period_ms = 1e3 / LidarConfig().rate
    scans = 10 if args.quick else 400
    repeats = 2 if args.quick else 15
    trials = 5 if args.quick else 300
    updates = timed("costmap updates per scan", lambda: costmap_updates(scans), failures)
    planned = timed("plans", lambda: plans(repeats), failures)
    quality = timed("the plans against the exact A*'s", lambda: planner_quality(trials), failures)
    if updates is not None:
        for name in ("no_map", "map"):
            updates[name]["share"] = updates[name]["ms"] / period_ms
            updates[name]["p95_share"] = updates[name]["p95_ms"] / period_ms
    if planned is not None:
        for entry in planned.values():
            entry["share"] = entry["plan_ms"] / period_ms
            entry["exact_search_share"] = entry["exact_search_ms"] / period_ms
    return {"lidar_period_ms": period_ms, "costmap": updates, "plan": planned, "quality": quality}


PLAN_LABELS = {
    "building": "the building as the map",
    "seen": "no map, the walls seen on the way",
    "open": "no obstacles",
}


def table(results: dict[str, Any]) -> str:
    """The section as a Markdown table."""
    lines = ["| navigation | ms | share of the lidar's period | detail |", "|---|---|---|---|"]
    updates, planned, quality = results["costmap"], results["plan"], results["quality"]
    if updates is not None:
        for name, label in (("no_map", "no map"), ("map", "the building as the map")):
            entry = updates[name]
            lines.append(
                f"| costmap update per scan, {label} | {fmt(entry['ms'], 2)} (p95 {fmt(entry['p95_ms'], 2)}) "
                f"| {fmt(100 * entry['share'], 1)} % | mark {fmt(entry['mark_ms'], 2)} ms, inflation "
                f"{fmt(entry['inflate_ms'], 2)} ms; {updates['scans']} scans, {entry['inflations']} inflations of "
                f"{fmt(entry['inflated_cells_per_inflation'])} cells each |"
            )
    for name, entry in (planned or {}).items():
        lines.append(
            f"| plan across, {PLAN_LABELS[name]} | {fmt(entry['plan_ms'], 1)} | {fmt(100 * entry['share'], 1)} % "
            f"| search {fmt(entry['route_ms'], 1)} ms, smoothing {fmt(entry['smooth_ms'], 1)} ms; "
            f"{fmt(entry['length_m'], 2)} m in {entry['points']} points |"
        )
        lines.append(
            f"| exact pure Python A* instead, {PLAN_LABELS[name]} | {fmt(entry['exact_search_ms'], 1)} "
            f"| {fmt(100 * entry['exact_search_share'], 1)} % | the search alone; smoothed "
            f"{fmt(entry['exact_length_m'], 2)} m; grid path cost {fmt(entry['exact_grid_path_cost'], 0)} against "
            f"{fmt(entry['grid_path_cost'], 0)} |"
        )
    if quality is not None:
        lines.append(
            f"| the plans against the exact A*'s, {quality['plans']} random maps | | | cost: median "
            f"{fmt(100 * quality['cost_median'], 1)} %, p10 {fmt(100 * quality['cost_p10'], 1)} %, p90 "
            f"{fmt(100 * quality['cost_p90'], 1)} %; {fmt(100 * quality['share_costing_5_percent_more'], 0)} % "
            f"of plans > 5 % costlier, {fmt(100 * quality['share_costing_5_percent_less'], 0)} % > 5 % cheaper; "
            f"length: median {fmt(100 * quality['length_median'], 1)} % |"
        )
    return "\n".join(lines)
