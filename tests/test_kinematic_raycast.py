"""The kinematic engine's vectorised lidar (sim_bridge/kinematic_world.py's RayCaster, casting every
ray at every body at once, and sensors.py's Lidar scan of arrays) reads the same bits as the
straightforward way: each shape in turn, a hit kept only when nearer, one PyBullet-style tuple a ray."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.messages import NO_HIT, LaserScan, Time
from services.config import LidarConfig
from sim_bridge.kinematic_world import Circle, RayCaster, Rectangle, Shape
from sim_bridge.sensors import Lidar, RayHit

Array = np.ndarray
RAY_HEIGHT = 0.1
MISS: RayHit = (NO_HIT, -1, 1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


# --- the reference: one shape at a time ---


def circle_hits(shape: Circle, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array, Array]:
    fx, fy = sx - shape.x, sy - shape.y
    a = dx * dx + dy * dy
    b = fx * dx + fy * dy
    c = fx * fx + fy * fy - shape.radius * shape.radius
    discriminant = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(discriminant)) / a
    hit = (discriminant >= 0.0) & (c > 0.0) & (t >= 0.0) & (t <= 1.0)
    at = np.where(hit, t, 0.0)
    return np.where(hit, t, np.inf), (fx + at * dx) / shape.radius, (fy + at * dy) / shape.radius


def rectangle_hits(shape: Rectangle, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array, Array]:
    cos, sin = math.cos(shape.yaw), math.sin(shape.yaw)
    lx, ly = cos * (sx - shape.x) + sin * (sy - shape.y), -sin * (sx - shape.x) + cos * (sy - shape.y)
    ldx, ldy = cos * dx + sin * dy, -sin * dx + cos * dy
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # a near-parallel ray: inf, as the engine's
        x1, x2 = (-shape.half_x - lx) / ldx, (shape.half_x - lx) / ldx
        y1, y2 = (-shape.half_y - ly) / ldy, (shape.half_y - ly) / ldy
    x_in, x_out = np.fmin(x1, x2), np.fmax(x1, x2)
    y_in, y_out = np.fmin(y1, y2), np.fmax(y1, y2)
    x_in = np.where(ldx == 0.0, np.where(np.abs(lx) < shape.half_x, -np.inf, np.inf), x_in)
    y_in = np.where(ldy == 0.0, np.where(np.abs(ly) < shape.half_y, -np.inf, np.inf), y_in)
    x_out = np.where(ldx == 0.0, np.inf, x_out)
    y_out = np.where(ldy == 0.0, np.inf, y_out)
    enter, leave = np.maximum(x_in, y_in), np.minimum(x_out, y_out)
    t = np.where((enter <= leave) & (enter > 0.0) & (enter <= 1.0), enter, np.inf)
    across_x = x_in >= y_in
    local_nx = np.where(across_x, -np.sign(ldx), 0.0)
    local_ny = np.where(across_x, 0.0, -np.sign(ldy))
    return t, cos * local_nx - sin * local_ny, sin * local_nx + cos * local_ny


def reference_cast(
    obstacles: list[Shape],
    robots: list[tuple[str, float, float]],
    caster: int,
    positions: list[tuple[float, float]],
    starts: Array,
    ends: Array,
) -> list[RayHit]:
    sx, sy, height = starts[:, 0], starts[:, 1], float(starts[0, 2])
    dx, dy = ends[:, 0] - sx, ends[:, 1] - sy
    best = np.full(len(sx), np.inf)
    body = np.full(len(sx), NO_HIT)
    nx, ny = np.zeros(len(sx)), np.zeros(len(sx))
    targets: list[tuple[int, Shape]] = list(enumerate(obstacles))
    for index, ((name, radius, top), (x, y)) in enumerate(zip(robots, positions, strict=True)):
        if index != caster:
            targets.append((len(obstacles) + index, Circle(name, x, y, radius, top)))
    for body_id, shape in targets:
        if not 0.0 <= height <= shape.height:
            continue
        hits = circle_hits if isinstance(shape, Circle) else rectangle_hits
        t, hit_nx, hit_ny = hits(shape, sx, sy, dx, dy)  # type: ignore[operator]
        nearer = t < best
        best = np.where(nearer, t, best)
        body = np.where(nearer, body_id, body)
        nx, ny = np.where(nearer, hit_nx, nx), np.where(nearer, hit_ny, ny)
    results: list[RayHit] = []
    for ray, (hit, t) in enumerate(zip(body.tolist(), best.tolist(), strict=True)):
        if hit == NO_HIT:
            results.append(MISS)
        else:
            position = (float(sx[ray] + t * dx[ray]), float(sy[ray] + t * dy[ray]), height)
            results.append((hit, -1, t, position, (float(nx[ray]), float(ny[ray]), 0.0)))
    return results


def reference_scan(lidar: Lidar, rng: np.random.Generator, hits: list[RayHit], names: dict[int, str]) -> LaserScan:
    config = lidar.config
    bodies = [hit[0] for hit in hits]
    ranges = lidar.starts + np.array([hit[2] for hit in hits]) * lidar.lengths
    if config.noise > 0.0:
        ranges = np.clip(ranges + rng.normal(0.0, config.noise, ranges.size), config.range_min, config.range_max)
    seen = sorted(set(bodies) - {NO_HIT})
    index_of = {body: index for index, body in enumerate(seen)} | {NO_HIT: NO_HIT}
    return LaserScan(
        tm=Time(0, 0),
        angle_min=config.angle_min,
        angle_increment=config.angle_increment,
        range_min=config.range_min,
        range_max=config.range_max,
        ranges=[None if body == NO_HIT else reading for body, reading in zip(bodies, ranges.tolist(), strict=True)],
        bodies=[names.get(body, f"body {body}") for body in seen],
        hits=[index_of[body] for body in bodies],
    )


# --- worlds and rays, on a coarse grid at times: ties, rays along sides, touching shapes ---

coordinate = st.one_of(st.integers(-8, 8).map(lambda n: n * 0.5), st.floats(-4.0, 4.0))
size = st.one_of(st.sampled_from([0.05, 0.1, 0.5, 1.0]), st.floats(0.01, 2.0))
height = st.sampled_from([0.05, 0.1, 0.5])
yaw = st.one_of(st.integers(-4, 4).map(lambda n: n * math.pi / 2), st.floats(-math.pi, math.pi))
rectangles = st.builds(Rectangle, st.sampled_from(["wall", "box"]), coordinate, coordinate, yaw, size, size, height)
circles = st.builds(Circle, st.just("post"), coordinate, coordinate, size, height)
shapes = st.lists(st.one_of(rectangles, circles), max_size=8).map(lambda s: s + s[: len(s) // 3])
"""Up to eight shapes, mixed in order, the first third twice over: equal entries."""


@st.composite
def scenes(draw: st.DrawFn) -> tuple[list[Shape], list[tuple[str, float, float]], int, list[tuple[float, float]]]:
    obstacles = draw(shapes)
    count = draw(st.integers(0, 3))
    robots = [(f"rh{index}", draw(size), draw(height)) for index in range(count)]
    positions = [(draw(coordinate), draw(coordinate)) for _ in range(count)]
    return obstacles, robots, draw(st.integers(0, max(count - 1, 0))), positions


@st.composite
def rays(draw: st.DrawFn) -> tuple[Array, Array]:
    count = draw(st.integers(1, 40))
    x, y, z = draw(coordinate), draw(coordinate), draw(st.sampled_from([RAY_HEIGHT, -0.1, 0.5]))
    headings = np.array(draw(st.lists(yaw, min_size=count, max_size=count)))
    lengths = np.array(draw(st.lists(st.floats(0.1, 6.0), min_size=count, max_size=count)))
    starts = np.column_stack([np.full(count, x), np.full(count, y), np.full(count, z)])
    ends = starts + np.column_stack([np.cos(headings) * lengths, np.sin(headings) * lengths, np.zeros(count)])
    return starts, ends


@settings(max_examples=400, deadline=None)
@given(scenes(), rays())
def test_casting_every_ray_at_every_body_at_once_hits_the_same_bits_as_one_body_at_a_time(scene, ray_set):
    obstacles, robots, caster, positions = scene
    starts, ends = ray_set
    expected = reference_cast(obstacles, robots, caster, positions, starts, ends)
    rays_caster = RayCaster(obstacles, robots)
    assert repr(rays_caster.cast(caster, positions, starts, ends)) == repr(expected)
    bodies, fractions = rays_caster.first_hits(caster, positions, starts, ends)
    assert bodies.tolist() == [hit[0] for hit in expected]
    assert repr(fractions.tolist()) == repr([hit[2] for hit in expected])


ENCLOSURE = [
    Rectangle("wall", 0.3, 1.0, 0.0, 2.0, 0.05, 0.5),
    Rectangle("wall", 0.3, -1.4, 0.0, 2.0, 0.05, 0.5),
    Rectangle("wall", 1.5, -0.2, 0.0, 0.05, 2.0, 0.5),
    Rectangle("wall", -0.9, -0.2, 0.0, 0.05, 2.0, 0.5),
]
"""Walls all round the lidar of the scan test, within its range: every ray hits."""


@settings(max_examples=200, deadline=None)
@given(scenes(), st.booleans(), st.sampled_from([0.0, 0.02]), st.integers(0, 3))
def test_the_lidar_scans_hits_and_arrays_of_them_as_it_scanned_hits_one_by_one(scene, enclosed, noise, stream):
    obstacles, robots, caster, positions = scene
    if enclosed:
        obstacles = obstacles + ENCLOSURE
    config = LidarConfig(rays=90, noise=noise, seed=5)
    lidar, tuples, arrays = (Lidar(config, 0.2, stream) for _ in range(3))
    starts, ends = lidar.rays((0.3, -0.2, RAY_HEIGHT), np.eye(3))
    rays_caster = RayCaster(obstacles, robots)
    hits = reference_cast(obstacles, robots, caster, positions, starts, ends)
    rng = np.random.default_rng([config.seed, stream])
    for _ in range(2):  # the second scan draws the noise where the first left off
        expected = reference_scan(lidar, rng, hits, rays_caster.names)
        assert tuples.scan(Time(0, 0), hits, rays_caster.names) == expected
        bodies, fractions = rays_caster.first_hits(caster, positions, starts, ends)
        assert arrays.scan_of(Time(0, 0), bodies, fractions, rays_caster.names) == expected
