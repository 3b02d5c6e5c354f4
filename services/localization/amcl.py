"""Adaptive Monte Carlo localization on a map (pure, numpy; nav2_amcl's model, docs/localization.md).

A :class:`ParticleFilter` holds particles (x, y, θ in ``map``, and weights). It is seeded about a pose
(:meth:`~ParticleFilter.seed`) or spread over the map's free cells
(:meth:`~ParticleFilter.global_localization`), then fed the odometry's pose (:meth:`~ParticleFilter.motion`:
the wheels' dead-reckoned pose in the odometry's own frame) and the lidar's scans
(:meth:`~ParticleFilter.update`). Once the odometry has moved ``update_min_d`` or turned
``update_min_a`` since the filter's last update (or on the first scan after a seed), a scan updates it:

- **motion**: each particle moves by the odometry's motion since the last update, sampled from
  nav2's ``diff`` model (Thrun et al., *Probabilistic Robotics*, table 5.6:
  ``sample_motion_model_odometry``): a turn ``rot1`` towards the direction of travel, a translation,
  a turn ``rot2``, each with Gaussian noise whose variance is ``alpha1``…``alpha4`` times the squared
  turns and distance; a turn's noise is measured from the nearer of forwards and backwards, so
  reversing is not a half turn;
- **sensor**: ``beams`` rays spread evenly over the scan, each ray's endpoint placed from the
  particle's pose and the lidar's mount; a ray that is not finite, below ``range_min`` or at
  ``range_max`` and beyond (nothing hit) is skipped, as nav2 skips max-range rays. Each ray's
  likelihood is nav2's ``likelihood_field`` model, p = z_hit·exp(−d²/2σ_hit²) + z_rand/range_max, d
  the endpoint's distance to the nearest obstacle's surface (services/localization/likelihood.py).
  The rays are combined as the product Π p (summed in logs), not as nav2's 1 + Σ p³: measured on the
  tests' room, the sum's weights are so flat that the heading follows the odometry's drift (0.04 rad
  off after 2 m with wheels 1 % off), where the product holds it within 0.01 rad and the position
  within 1 to 2 cm RMS; the z_rand floor bounds what any one ray can cost, so a ray that hits
  something not on the map cannot rule a particle out;
- **recovery** (augmented MCL, Thrun et al. table 8.3, nav2's ``recovery_alpha_slow``/``_fast``): a
  slow and a fast average of the scan's fit, the likelihood per ray (geometric mean) of the particles
  the scan favours; while the fast is below the slow (the scans stopped fitting: the robot was
  kidnapped, or the seed was wrong), a share 1 − fast/slow of the resampled particles is drawn
  uniformly over the free cells. Unlike nav2, the averages are not restarted after drawing (the slow
  one would forget what a good fit is after the first draw, and a kidnapped robot would get a single
  burst of random particles), and the fit is weighted by the scan, so that the random particles it
  rules out do not keep it low;
- **resampling** every ``resample_interval`` updates: low-variance (systematic) resampling to a count
  chosen by KLD sampling (Fox 2003, nav2's ``pf_err`` and ``pf_z``) from the bins of 0.5 m × 0.5 m ×
  10° the resampled particles (random ones included, as nav2's) occupy, between ``min_particles`` and ``max_particles``; the count for a
  single bin is ``min_particles`` (nav2 gives ``max_particles`` there, a discontinuity).

The estimate is the weighted mean of the particles as the last scan weighted them, before resampling
(θ's circular mean), and their covariance (nav2 reports its largest cluster's: the same once
converged; not while several hypotheses live, when the mean lies between them). An update whose estimate moves further than
``max_jump`` (or turns further than ``max_jump_angle``) beyond the odometry's motion since the
previous estimate counts as a jump, when the previous estimate was converged (its spread within those
bounds) and not the first after a seed: a seed is meant to move the estimate.

Every draw comes from the :class:`numpy.random.Generator` given, so the same generator's state, scans
and odometry give the same particles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.codec import BadInput
from services.config.amcl import AmclConfig
from services.config.sensors import LidarConfig
from services.localization.likelihood import LikelihoodField
from services.planar import Pose, compose, relative_motion, wrap_angle

Floats = npt.NDArray[np.float64]

BIN_XY = 0.5
"""m: a KLD histogram bin's side in x and y (nav2's pf kd-tree)."""
BIN_THETA = math.radians(10.0)
"""rad: a KLD histogram bin's width in θ."""
SMALL_TRANSLATION = 0.01
"""m: below this the direction of travel is noise, and ``rot1`` is 0 (nav2's diff model)."""


@dataclass(frozen=True)
class Estimate:
    """The filter's estimate: the particles' weighted mean pose and their covariance (x, y, θ; m, rad)."""

    pose: Pose
    covariance: Floats


def wrap_angles(angles: Floats) -> Floats:
    """Angles wrapped into [−π, π)."""
    return np.asarray((angles + math.pi) % (2.0 * math.pi) - math.pi, dtype=np.float64)


def kld_limit(bins: npt.NDArray[np.int64], settings: AmclConfig) -> npt.NDArray[np.int64]:
    """The particles KLD sampling asks for, given how many bins they occupy (Fox 2003, nav2's
    ``pf_resample_limit``), within [``min_particles``, ``max_particles``]."""
    k = np.maximum(bins - 1, 1).astype(np.float64)
    b = 2.0 / (9.0 * k)
    x = 1.0 - b + np.sqrt(b) * settings.kld_z
    wanted = np.ceil(k / (2.0 * settings.kld_err) * x**3)
    wanted = np.where(bins <= 1, settings.min_particles, wanted)
    return np.clip(wanted, settings.min_particles, settings.max_particles).astype(np.int64)


def systematic_resample(weights: Floats, count: int, rng: np.random.Generator) -> npt.NDArray[np.intp]:
    """``count`` indices drawn by low-variance (systematic) resampling from normalized ``weights``."""
    positions = (rng.random() + np.arange(count)) / count
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0  # rounding must not leave the last position past the end
    return np.minimum(np.searchsorted(cumulative, positions, side="right"), weights.size - 1)


class ParticleFilter:
    """Adaptive Monte Carlo localization on one map (see the module's docstring)."""

    def __init__(
        self, field: LikelihoodField, settings: AmclConfig, lidar: LidarConfig, rng: np.random.Generator
    ) -> None:
        self._field = field
        self._settings = settings
        self._lidar = lidar
        self._rng = rng
        rays, beams = lidar.rays, settings.beams
        self._beam_rays = np.arange(rays) if beams >= rays else np.arange(beams) * rays // beams
        self._ray_table_range_max = math.nan
        self._ray_table: Floats = np.empty(0)
        self._xs: Floats = np.empty(0)
        self._ys: Floats = np.empty(0)
        self._thetas: Floats = np.empty(0)
        self._weights: Floats = np.empty(0)
        self._odometry: Pose | None = None
        """The latest odometry pose."""
        self._odometry_at_update: Pose | None = None
        """The odometry pose the particles were last moved to."""
        self._reseeded = False
        """Seeded since the last update: the next scan updates whatever the motion."""
        self._w_slow = 0.0
        self._w_fast = 0.0
        self._updates_since_resample = 0
        self._estimate: Estimate | None = None
        """The estimate of the last update (the particles weighted by its scan, before resampling: the
        random particles the resampling draws are weighed by no scan yet), or of the seed."""
        self._previous: Estimate | None = None
        """The estimate of the last update (None after a seed): what a jump is measured from."""
        self._odometry_at_previous: Pose | None = None
        self.updates = 0
        self.resamples = 0
        self.random_particles = 0
        """Random particles drawn by the recovery, in all."""
        self.recoveries = 0
        """Resamplings that drew random particles."""
        self.jumps = 0
        self.last_jump = ""
        """What the last jump was: when, and by how much (empty: none yet)."""

    @property
    def xs(self) -> Floats:
        return self._read_only(self._xs)

    @property
    def ys(self) -> Floats:
        return self._read_only(self._ys)

    @property
    def thetas(self) -> Floats:
        return self._read_only(self._thetas)

    @property
    def weights(self) -> Floats:
        """The particles' weights, normalized (summing to 1)."""
        return self._read_only(self._weights)

    @staticmethod
    def _read_only(array: Floats) -> Floats:
        view = array.view()
        view.flags.writeable = False
        return view

    def seed(self, pose: Pose, covariance: npt.ArrayLike | None = None) -> None:
        """``max_particles`` particles drawn from a Gaussian about ``pose`` (in ``map``) of
        ``covariance`` (3 × 3, x, y, θ; None: ``initial_sigma_xy`` and ``initial_sigma_theta``).
        BadInput, changing nothing, for a pose that is not finite or off the map, or a covariance that
        is not a finite symmetric positive semi-definite 3 × 3 matrix."""
        if not all(math.isfinite(value) for value in pose):
            raise BadInput(f"seed pose {tuple(pose)} is not finite")
        geometry = self._field.geometry
        if not geometry.contains(pose.x, pose.y):
            raise BadInput(
                f"seed pose ({pose.x:g}, {pose.y:g}) m is off the map "
                f"([{geometry.origin_x:g}, {geometry.max_x:g}) × [{geometry.origin_y:g}, {geometry.max_y:g}) m)"
            )
        if covariance is None:
            sigma_xy, sigma_theta = self._settings.initial_sigma_xy, self._settings.initial_sigma_theta
            matrix = np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2])
        else:
            matrix = self._checked_covariance(covariance)
        count = self._settings.max_particles
        draws = self._rng.multivariate_normal(np.zeros(3), matrix, size=count, method="eigh")
        self._reset(pose.x + draws[:, 0], pose.y + draws[:, 1], wrap_angles(pose.theta + draws[:, 2]))

    @staticmethod
    def _checked_covariance(covariance: npt.ArrayLike) -> Floats:
        try:
            matrix = np.array(covariance, dtype=np.float64)
        except (TypeError, ValueError):
            raise BadInput("seed covariance is not a 3 × 3 matrix of numbers") from None
        if matrix.shape != (3, 3):
            raise BadInput(f"seed covariance of shape {matrix.shape}, not 3 × 3")
        if not np.isfinite(matrix).all():
            raise BadInput("seed covariance is not finite")
        if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=1e-12):
            raise BadInput("seed covariance is not symmetric")
        if np.linalg.eigvalsh(matrix).min() < -1e-12:
            raise BadInput("seed covariance is not positive semi-definite")
        return matrix

    def global_localization(self) -> None:
        """``max_particles`` particles spread uniformly over the map's free cells, headings uniform."""
        count = self._settings.max_particles
        xs, ys = self._field.free_points(count, self._rng)
        self._reset(xs, ys, self._rng.uniform(-math.pi, math.pi, count))

    def _reset(self, xs: Floats, ys: Floats, thetas: Floats) -> None:
        self._xs, self._ys, self._thetas = xs, ys, thetas
        self._weights = np.full(xs.size, 1.0 / xs.size)
        self._odometry_at_update = self._odometry
        self._reseeded = True
        self._w_slow = self._w_fast = 0.0
        self._updates_since_resample = 0
        self._previous = None
        self._estimate = self._weighted_estimate()

    def motion(self, odometry_pose: Pose) -> None:
        """The odometry's latest pose (its own frame): the particles move by its motion at the next
        update. BadInput, changing nothing, for a pose that is not finite."""
        if not all(math.isfinite(value) for value in odometry_pose):
            raise BadInput(f"odometry pose {tuple(odometry_pose)} is not finite")
        self._odometry = Pose(*odometry_pose)
        if self._odometry_at_update is None:
            self._odometry_at_update = self._odometry

    def update(
        self, scan_ranges: npt.ArrayLike, angle_min: float, angle_increment: float, range_min: float, range_max: float
    ) -> bool:
        """Updates the filter with a scan (its ranges, m; NaN or inf where nothing was hit) if the
        odometry moved enough since the last update, or the filter was seeded since; True if it did.
        BadInput, changing nothing, for a scan whose ray count is not the lidar's or whose angles or
        limits are not finite and ordered."""
        ranges = np.asarray(scan_ranges, dtype=np.float64)
        if ranges.shape != (self._lidar.rays,):
            raise BadInput(f"a scan of {ranges.size} ranges for a lidar of {self._lidar.rays} rays")
        if not all(math.isfinite(value) for value in (angle_min, angle_increment, range_min, range_max)):
            raise BadInput("a scan's angles and range limits must be finite")
        if not 0.0 <= range_min < range_max:
            raise BadInput(f"a scan's range limits [{range_min}, {range_max}] are not 0 <= min < max")
        if self._xs.size == 0:
            return False
        motion = self._pending_motion()
        if not self._reseeded and not self._moved_enough(motion):
            return False
        beam_ranges = ranges[self._beam_rays]
        valid = np.isfinite(beam_ranges) & (beam_ranges >= range_min) & (beam_ranges < range_max)
        if not valid.any():  # no ray hit anything: the scan says nothing
            return False
        self._move(motion)
        self._odometry_at_update = self._odometry
        angles = np.asarray(self._lidar.yaw + angle_min + self._beam_rays[valid] * angle_increment, dtype=np.float64)
        self._weigh(beam_ranges[valid], angles, range_max)
        estimate = self._estimate = self._weighted_estimate()
        self._updates_since_resample += 1
        if self._updates_since_resample >= self._settings.resample_interval:
            self._resample()
            self._updates_since_resample = 0
        self.updates += 1
        self._check_jump(estimate)
        self._reseeded = False
        return True

    def _pending_motion(self) -> Pose:
        if self._odometry is None or self._odometry_at_update is None:
            return Pose(0.0, 0.0, 0.0)
        return relative_motion(self._odometry_at_update, self._odometry)

    def _moved_enough(self, motion: Pose) -> bool:
        settings = self._settings
        return math.hypot(motion.x, motion.y) >= settings.update_min_d or abs(motion.theta) >= settings.update_min_a

    def _move(self, motion: Pose) -> None:
        """nav2's ``diff`` model: the odometry's motion as rot1, translation, rot2, each sampled with noise."""
        settings, count = self._settings, self._xs.size
        translation = math.hypot(motion.x, motion.y)
        rot1 = 0.0 if translation < SMALL_TRANSLATION else math.atan2(motion.y, motion.x)
        rot2 = wrap_angle(motion.theta - rot1)
        # a turn's noise from the nearer of forwards and backwards: reversing is not a half turn
        rot1_noise = min(abs(rot1), abs(wrap_angle(rot1 - math.pi)))
        rot2_noise = min(abs(rot2), abs(wrap_angle(rot2 - math.pi)))
        sigma_rot1 = math.sqrt(settings.alpha1 * rot1_noise**2 + settings.alpha2 * translation**2)
        sigma_translation = math.sqrt(
            settings.alpha3 * translation**2 + settings.alpha4 * (rot1_noise**2 + rot2_noise**2)
        )
        sigma_rot2 = math.sqrt(settings.alpha1 * rot2_noise**2 + settings.alpha2 * translation**2)
        noise = self._rng.standard_normal((3, count))
        rot1_hat = rot1 - sigma_rot1 * noise[0]
        translation_hat = translation - sigma_translation * noise[1]
        rot2_hat = rot2 - sigma_rot2 * noise[2]
        heading = self._thetas + rot1_hat
        self._xs = self._xs + translation_hat * np.cos(heading)
        self._ys = self._ys + translation_hat * np.sin(heading)
        self._thetas = wrap_angles(heading + rot2_hat)

    def _ray_log_likelihood(self, range_max: float) -> Floats:
        """log p of a ray ending in each cell (and off the map), p = z_hit·exp(−d²/2σ²) + z_rand/range_max:
        built once per ``range_max`` so that an update only looks it up."""
        if range_max != self._ray_table_range_max:
            settings = self._settings
            distance = self._field.table
            p = settings.z_hit * np.exp(-(distance**2) / (2.0 * settings.sigma_hit**2)) + settings.z_rand / range_max
            self._ray_table = np.log(p)
            self._ray_table_range_max = range_max
        return self._ray_table

    def _weigh(self, ranges: Floats, angles: Floats, range_max: float) -> None:
        """Each particle's weight times its scan's likelihood, Π p over the rays (in logs)."""
        lidar = self._lidar
        # the rays' endpoints on the base frame, then in map for every particle at once (particles × rays)
        end_x = lidar.x + ranges * np.cos(angles)
        end_y = lidar.y + ranges * np.sin(angles)
        cos, sin = np.cos(self._thetas)[:, None], np.sin(self._thetas)[:, None]
        map_x = self._xs[:, None] + cos * end_x - sin * end_y
        map_y = self._ys[:, None] + sin * end_x + cos * end_y
        log_likelihood = self._ray_log_likelihood(range_max).take(self._field.indices(map_x, map_y)).sum(axis=1)
        with np.errstate(divide="ignore"):  # a weight that underflowed to 0 stays 0
            log_weights = np.log(self._weights) + log_likelihood
        weights = np.exp(log_weights - log_weights.max())
        self._weights = weights / weights.sum()
        # the fit: the likelihood per ray (a geometric mean, in (0, 1] whatever the number of rays) of
        # the particles the scan favours, weighted by it; the random particles the scan rules out do
        # not drag it down (averaged over all, they would keep the fit low, and draw more of them)
        self._update_fit_averages(float(self._weights @ np.exp(log_likelihood / ranges.size)))

    def _update_fit_averages(self, fit: float) -> None:
        """The slow and the fast averages of the scans' fit (nav2's ``w_slow`` and ``w_fast``); an
        average at 0 (after a seed or a recovery) starts from this fit."""
        settings = self._settings
        self._w_slow = (
            fit if self._w_slow == 0.0 else self._w_slow + settings.recovery_alpha_slow * (fit - self._w_slow)
        )
        self._w_fast = (
            fit if self._w_fast == 0.0 else self._w_fast + settings.recovery_alpha_fast * (fit - self._w_fast)
        )

    def _resample(self) -> None:
        """Low-variance resampling to the count KLD sampling asks for, a share of it drawn at random
        over the free cells while the fast average of the fit is below the slow (augmented MCL)."""
        settings, rng = self._settings, self._rng
        recovering = settings.recovery_alpha_slow > 0.0 and settings.recovery_alpha_fast > 0.0
        random_share = max(0.0, 1.0 - self._w_fast / self._w_slow) if recovering and self._w_slow > 0.0 else 0.0
        trial_count = settings.max_particles
        is_random = rng.random(trial_count) < random_share
        random_count = int(is_random.sum())
        random_xs, random_ys = self._field.free_points(random_count, rng)
        random_thetas = rng.uniform(-math.pi, math.pi, random_count)
        trial = rng.permutation(systematic_resample(self._weights, trial_count, rng))
        trial_xs, trial_ys, trial_thetas = self._xs[trial], self._ys[trial], self._thetas[trial]
        trial_xs[is_random], trial_ys[is_random], trial_thetas[is_random] = random_xs, random_ys, random_thetas
        count = self._kld_count(trial_xs, trial_ys, trial_thetas)
        # the random particles among the first `count` of the trial are kept; the rest is resampled
        # anew at that count, low-variance (the trial's order is random, not low-variance)
        kept_random = is_random[:count]
        kept = systematic_resample(self._weights, count - int(kept_random.sum()), rng)
        self._xs = np.concatenate([self._xs[kept], trial_xs[:count][kept_random]])
        self._ys = np.concatenate([self._ys[kept], trial_ys[:count][kept_random]])
        self._thetas = np.concatenate([self._thetas[kept], trial_thetas[:count][kept_random]])
        self._weights = np.full(count, 1.0 / count)
        if kept_random.any():
            self.random_particles += int(kept_random.sum())
            self.recoveries += 1
        self.resamples += 1

    def _kld_count(self, xs: Floats, ys: Floats, thetas: Floats) -> int:
        """How many particles to keep: the first count, of particles taken in random order, that exceeds
        what KLD sampling asks for the bins those first ones fill (nav2's loop over its kd-tree)."""
        settings = self._settings
        if settings.min_particles == settings.max_particles:
            return settings.max_particles
        bin_x = np.floor(xs / BIN_XY).astype(np.int64)
        bin_y = np.floor(ys / BIN_XY).astype(np.int64)
        bin_theta = np.floor((thetas + math.pi) / BIN_THETA).astype(np.int64)
        bin_x -= bin_x.min()
        bin_y -= bin_y.min()
        keys = (bin_x * (int(bin_y.max()) + 1) + bin_y) * (int(bin_theta.max()) + 1) + bin_theta
        _, first = np.unique(keys, return_index=True)
        is_new_bin = np.zeros(xs.size, dtype=bool)
        is_new_bin[first] = True
        counts = np.arange(1, xs.size + 1)
        enough = counts > kld_limit(np.cumsum(is_new_bin), settings)
        return int(counts[np.argmax(enough)]) if enough.any() else settings.max_particles

    def estimate(self) -> Estimate:
        """The estimate of the last update, or of the seed; ValueError before a seed."""
        if self._estimate is None:
            raise ValueError("no particles: the filter has not been seeded")
        return self._estimate

    def _weighted_estimate(self) -> Estimate:
        """The particles' weighted mean pose (θ's circular mean) and covariance."""
        weights = self._weights
        x, y = float(weights @ self._xs), float(weights @ self._ys)
        theta = math.atan2(float(weights @ np.sin(self._thetas)), float(weights @ np.cos(self._thetas)))
        deviations = np.stack([self._xs - x, self._ys - y, wrap_angles(self._thetas - theta)])
        covariance = (deviations * weights) @ deviations.T
        return Estimate(Pose(x, y, theta), covariance)

    def _check_jump(self, estimate: Estimate) -> None:
        """Counts a jump if the estimate moved beyond the odometry's motion since the previous one."""
        previous, settings = self._previous, self._settings
        if previous is not None and self._converged(previous):
            odometry = Pose(0.0, 0.0, 0.0)
            if self._odometry is not None and self._odometry_at_previous is not None:
                odometry = relative_motion(self._odometry_at_previous, self._odometry)
            expected = compose(previous.pose, odometry)
            distance = math.hypot(estimate.pose.x - expected.x, estimate.pose.y - expected.y)
            turn = abs(wrap_angle(estimate.pose.theta - expected.theta))
            if distance > settings.max_jump or turn > settings.max_jump_angle:
                self.jumps += 1
                self.last_jump = (
                    f"update {self.updates}: the estimate moved {distance:.3f} m and turned {turn:.3f} rad "
                    f"beyond the odometry's motion (max_jump {settings.max_jump:g} m, "
                    f"max_jump_angle {settings.max_jump_angle:g} rad)"
                )
        self._previous = estimate
        self._odometry_at_previous = self._odometry

    def _converged(self, estimate: Estimate) -> bool:
        covariance = estimate.covariance
        return (
            math.sqrt(covariance[0, 0] + covariance[1, 1]) <= self._settings.max_jump
            and math.sqrt(covariance[2, 2]) <= self._settings.max_jump_angle
        )
