"""The particle filter (services/localization/amcl.py) in the synthetic room of tests/amcl_world.py:
convergence, tracking, global localization, kidnapping, bad input, the adaptive count, determinism
and jumps; the motion model, KLD sampling and resampling as properties."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.config.amcl import AmclConfig
from services.localization.amcl import ParticleFilter, kld_limit, systematic_resample
from services.localization.likelihood import LikelihoodField
from services.planar import Pose, compose, relative_motion, wrap_angle
from tests import amcl_world as world

LIDAR = world.LIDAR
FIELD = LikelihoodField(world.room_grid(), AmclConfig().likelihood_max_dist)


def new_filter(seed: int = 0, **changes: object) -> ParticleFilter:
    particle_filter = ParticleFilter(FIELD, AmclConfig(**changes), LIDAR, np.random.default_rng(seed))  # type: ignore[arg-type]
    particle_filter.motion(Pose(0.0, 0.0, 0.0))
    return particle_filter


def scan(particle_filter: ParticleFilter, ranges: np.ndarray) -> bool:
    return particle_filter.update(ranges, LIDAR.angle_min, LIDAR.angle_increment, LIDAR.range_min, LIDAR.range_max)


def errors(particle_filter: ParticleFilter, true: Pose) -> tuple[float, float]:
    estimate = particle_filter.estimate().pose
    return math.hypot(estimate.x - true.x, estimate.y - true.y), abs(wrap_angle(estimate.theta - true.theta))


def follow(particle_filter: ParticleFilter, path: Iterable[tuple[Pose, Pose]], seed: int) -> list[tuple[float, float]]:
    """Feeds the odometry and a noisy scan at each step; the errors after each filter update."""
    rng = np.random.default_rng(seed)
    found = []
    for true, odometry in path:
        particle_filter.motion(odometry)
        if scan(particle_filter, world.cast(true, rng)):
            found.append(errors(particle_filter, true))
    return found


def offset(pose: Pose, dx: float, dtheta: float) -> Pose:
    return Pose(pose.x + dx, pose.y, pose.theta + dtheta)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_converges_from_a_seed_half_a_metre_off(seed: int) -> None:
    particle_filter = new_filter(seed)
    particle_filter.seed(offset(world.loop_pose(0.0), 0.5, 0.3))
    found = np.array(follow(particle_filter, world.drive(30.0), seed))
    # within 20 s (about 80 updates), and from then on
    assert (found[80:, 0] < 0.05).all() and (found[80:, 1] < 0.03).all(), found[80:].max(axis=0)


def test_tracks_two_minutes_of_driving_within_3_cm_rms() -> None:
    particle_filter = new_filter(3)
    particle_filter.seed(world.loop_pose(0.0), np.diag([0.05**2, 0.05**2, 0.05**2]))
    found = np.array(follow(particle_filter, world.drive(120.0), 3))
    assert len(found) > 300
    assert math.sqrt(np.mean(found[:, 0] ** 2)) < 0.03
    assert math.sqrt(np.mean(found[:, 1] ** 2)) < 0.03
    assert particle_filter.jumps == 0, particle_filter.last_jump


def test_global_localization_finds_the_pose_in_an_asymmetric_room() -> None:
    particle_filter = new_filter(7)
    particle_filter.global_localization()
    assert particle_filter.xs.size == AmclConfig().max_particles
    found = follow(particle_filter, world.drive(30.0), 0)
    assert found[-1][0] < 0.05 and found[-1][1] < 0.03, found[-1]
    assert particle_filter.jumps == 0, particle_filter.last_jump


def test_a_kidnapped_robot_is_found_again_by_the_random_particles() -> None:
    particle_filter = new_filter(2)
    particle_filter.seed(world.loop_pose(0.0), np.diag([1e-4, 1e-4, 1e-4]))
    wheels = world.WheelOdometry()
    before = follow(particle_filter, world.drive(15.0, odometry=wheels), 2)
    assert before[-1][0] < 0.05
    # carried 4 m further along the loop, the wheels turning nowhere meanwhile
    after = follow(particle_filter, world.drive(60.0, start=3.0 + 4.0, odometry=wheels), 3)
    assert after[0][0] > 1.0
    assert particle_filter.random_particles > 1000  # a few now and then while tracking; many once lost
    assert after[-1][0] < 0.05 and after[-1][1] < 0.03, after[-1]
    assert particle_filter.jumps >= 1 and "beyond the odometry's motion" in particle_filter.last_jump


def state(particle_filter: ParticleFilter) -> tuple[object, ...]:
    return (
        particle_filter.xs.copy(),
        particle_filter.ys.copy(),
        particle_filter.thetas.copy(),
        particle_filter.weights.copy(),
        particle_filter.estimate(),
        particle_filter.updates,
        particle_filter.jumps,
        particle_filter.random_particles,
    )


def assert_same(first: tuple[object, ...], second: tuple[object, ...]) -> None:
    for a, b in zip(first, second, strict=True):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        elif hasattr(a, "covariance"):
            assert a.pose == b.pose  # type: ignore[attr-defined]
            np.testing.assert_array_equal(a.covariance, b.covariance)  # type: ignore[attr-defined]
        else:
            assert a == b


@pytest.mark.parametrize(
    ("pose", "covariance", "reason"),
    [
        (Pose(-3.0, 1.0, 0.0), None, "off the map"),
        (Pose(1.0, 99.0, 0.0), None, "off the map"),
        (Pose(math.nan, 1.0, 0.0), None, "not finite"),
        (Pose(1.0, 1.0, math.inf), None, "not finite"),
        (Pose(1.0, 1.0, 0.0), np.eye(2), "3 × 3"),
        (Pose(1.0, 1.0, 0.0), np.full((3, 3), math.nan), "not finite"),
        (Pose(1.0, 1.0, 0.0), np.diag([1.0, -1.0, 1.0]), "positive semi-definite"),
        (Pose(1.0, 1.0, 0.0), [[1, 2, 0], [0, 1, 0], [0, 0, 1]], "not symmetric"),
    ],
)
def test_a_bad_seed_raises_and_changes_nothing(pose: Pose, covariance: object, reason: str) -> None:
    particle_filter = new_filter()
    particle_filter.seed(world.loop_pose(0.0))
    before = state(particle_filter)
    with pytest.raises(BadInput, match=reason):
        particle_filter.seed(pose, covariance)  # type: ignore[arg-type]
    assert_same(before, state(particle_filter))


def test_a_bad_scan_or_odometry_raises_and_changes_nothing() -> None:
    particle_filter = new_filter()
    particle_filter.seed(world.loop_pose(0.0))
    ranges = world.cast(world.loop_pose(0.0))
    before = state(particle_filter)
    with pytest.raises(BadInput, match="359 ranges for a lidar of 360"):
        scan(particle_filter, ranges[:-1])
    with pytest.raises(BadInput, match="finite"):
        particle_filter.update(ranges, math.nan, LIDAR.angle_increment, LIDAR.range_min, LIDAR.range_max)
    with pytest.raises(BadInput, match="range limits"):
        particle_filter.update(ranges, LIDAR.angle_min, LIDAR.angle_increment, 3.0, 1.0)
    with pytest.raises(BadInput, match="not finite"):
        particle_filter.motion(Pose(0.0, math.nan, 0.0))
    assert_same(before, state(particle_filter))
    assert scan(particle_filter, ranges)  # the first scan after a seed updates, motion or not


def test_a_scan_with_no_return_or_no_motion_does_not_update() -> None:
    particle_filter = new_filter()
    particle_filter.seed(world.loop_pose(0.0))
    assert not scan(particle_filter, np.full(LIDAR.rays, math.inf))
    ranges = world.cast(world.loop_pose(0.0))
    assert scan(particle_filter, ranges)
    assert not scan(particle_filter, ranges)  # no motion since
    particle_filter.motion(Pose(0.06, 0.0, 0.0))
    assert scan(particle_filter, ranges)
    assert particle_filter.updates == 2


def test_the_particle_count_adapts_to_the_spread() -> None:
    settings = AmclConfig()
    particle_filter = new_filter(4)
    true = world.loop_pose(0.0)
    particle_filter.seed(offset(true, 0.3, 0.2), np.diag([0.5**2, 0.5**2, 0.5**2]))
    # a scan with a single return says little: the particles stay spread over many bins
    ranges = np.full(LIDAR.rays, math.inf)
    ranges[0] = world.cast(true)[0]
    assert scan(particle_filter, ranges)
    assert particle_filter.xs.size > 2 * settings.min_particles
    follow(particle_filter, world.drive(15.0), 4)
    assert particle_filter.xs.size <= settings.min_particles + 1


def test_the_same_seed_gives_the_same_estimates() -> None:
    runs = []
    for _ in range(2):
        particle_filter = new_filter(11)
        particle_filter.seed(offset(world.loop_pose(0.0), 0.2, 0.1))
        follow(particle_filter, world.drive(5.0), 5)
        runs.append(state(particle_filter))
    assert_same(runs[0], runs[1])


def test_a_reseed_is_no_jump_but_a_forced_change_is() -> None:
    particle_filter = new_filter(5)
    particle_filter.seed(world.loop_pose(0.0), np.diag([1e-4, 1e-4, 1e-4]))
    wheels = world.WheelOdometry()
    follow(particle_filter, world.drive(5.0, odometry=wheels), 5)
    # reseeded 1 m off: the estimate moves by a metre, on purpose
    true = world.loop_pose(1.0)
    particle_filter.seed(offset(true, 1.0, 0.0), np.diag([1e-4, 1e-4, 1e-4]))
    assert scan(particle_filter, world.cast(true))
    assert particle_filter.jumps == 0
    # converged there, then forced back to the truth by a seed the filter had not asked for
    particle_filter.motion(compose(wheels.pose, Pose(0.1, 0.0, 0.0)))
    assert scan(particle_filter, world.cast(true))
    particle_filter._xs = particle_filter._xs - 1.0  # as a wrong update would move it
    particle_filter.motion(compose(wheels.pose, Pose(0.2, 0.0, 0.0)))
    assert scan(particle_filter, world.cast(true))
    assert particle_filter.jumps == 1
    assert particle_filter.last_jump.startswith(f"update {particle_filter.updates}: the estimate moved 1.0")


@settings(max_examples=50, deadline=None)
@given(
    start=st.tuples(st.floats(0.5, 5.5), st.floats(0.5, 3.5), st.floats(-math.pi, math.pi)),
    distance=st.just(0.0) | st.floats(0.011, 0.5),
    direction=st.floats(-math.pi, math.pi),
    turn=st.floats(-math.pi, math.pi),
)
def test_without_noise_every_particle_moves_by_the_odometry(
    start: tuple[float, float, float], distance: float, direction: float, turn: float
) -> None:
    # any motion of at least 1 cm (below, the model takes the direction of travel for noise: rot1 = 0)
    motion = (distance * math.cos(direction), distance * math.sin(direction), turn)
    particle_filter = ParticleFilter(
        FIELD,
        AmclConfig(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, min_particles=20, max_particles=20),
        LIDAR,
        np.random.default_rng(0),
    )
    particle_filter.motion(Pose(1.0, 2.0, 0.5))
    seed = Pose(*start)
    particle_filter.seed(seed, np.zeros((3, 3)))
    odometry_end = compose(Pose(1.0, 2.0, 0.5), Pose(*motion))
    particle_filter._move(relative_motion(Pose(1.0, 2.0, 0.5), odometry_end))
    expected = compose(seed, relative_motion(Pose(1.0, 2.0, 0.5), odometry_end))
    np.testing.assert_allclose(particle_filter.xs, expected.x, atol=1e-9)
    np.testing.assert_allclose(particle_filter.ys, expected.y, atol=1e-9)
    assert np.abs(np.vectorize(wrap_angle)(particle_filter.thetas - expected.theta)).max() < 1e-9


@settings(max_examples=100, deadline=None)
@given(bins=st.lists(st.integers(0, 5000), min_size=1, max_size=50), minimum=st.integers(1, 3000))
def test_kld_limit_grows_with_the_bins_within_the_bounds(bins: list[int], minimum: int) -> None:
    settings = AmclConfig(min_particles=minimum, max_particles=max(minimum, 2000))
    ordered = np.sort(np.array(bins, dtype=np.int64))
    limits = kld_limit(ordered, settings)
    assert (np.diff(limits) >= 0).all()
    assert (limits >= settings.min_particles).all() and (limits <= settings.max_particles).all()


@settings(max_examples=100, deadline=None)
@given(
    weights=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=50).filter(lambda w: sum(w) > 1e-6),
    count=st.integers(1, 500),
    seed=st.integers(0, 2**32 - 1),
)
def test_systematic_resampling_draws_each_in_proportion(weights: list[float], count: int, seed: int) -> None:
    normalized = np.array(weights) / sum(weights)
    drawn = systematic_resample(normalized, count, np.random.default_rng(seed))
    assert drawn.size == count and ((drawn >= 0) & (drawn < normalized.size)).all()
    copies = np.bincount(drawn, minlength=normalized.size)
    assert (np.abs(copies - normalized * count) <= 1.0 + 1e-9).all()


@settings(max_examples=20, deadline=None)
@given(
    ranges=st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(0.0, 4.0)), min_size=360, max_size=360
    ),
    seed=st.integers(0, 2**32 - 1),
)
def test_any_scan_of_the_right_length_keeps_the_weights_a_distribution(ranges: list[float], seed: int) -> None:
    particle_filter = new_filter(seed, min_particles=100, max_particles=200)
    particle_filter.seed(world.loop_pose(0.0))
    scan(particle_filter, np.array(ranges))
    weights = particle_filter.weights
    assert np.isfinite(weights).all() and (weights >= 0).all() and math.isclose(weights.sum(), 1.0)
    assert np.isfinite(particle_filter.estimate().covariance).all()
