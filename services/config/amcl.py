"""The amcl section of the robot description: the particle filter that localizes the robot on the map
from the lidar's scans and the wheels' odometry (services/localization/amcl.py; nav2_amcl's model,
its parameter named beside each field where one corresponds).

The defaults are tuned by measurement (benchmarks/amcl.py, tests/test_amcl.py) for the default robot:
a 360-ray lidar at 10 Hz reaching 3.5 m with σ ≈ 1 cm of noise, wheel odometry about 1 % off in its
wheel radii and axle, a map of 5 cm cells.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from schemas.navigation import MAX_PARTICLES
from services.config.fields import METRES, RADIANS, NonNegative, Positive, Section

Particles = Annotated[int, msgspec.Meta(ge=1, le=MAX_PARTICLES)]
Fraction = Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)]
Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Rate = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]


class AmclConfig(Section, frozen=True):
    """Adaptive Monte Carlo localization (docs/localization.md): particles moved by the odometry's
    motion, weighted by how well the scan fits the map's likelihood field, resampled to a number that
    adapts to their spread (KLD sampling), with random particles added when the fit collapses
    (augmented MCL: a kidnapped robot is found again)."""

    min_particles: Particles = 500
    """The fewest particles the filter keeps (nav2's ``min_particles``): the count a converged filter
    settles to."""
    max_particles: Particles = 2000
    """The most (nav2's ``max_particles``): a seed and a global localization start with this many;
    equal to ``min_particles``, a fixed count."""
    kld_err: Fraction = 0.05
    """KLD sampling's bound on the error between the particles' and the true distribution (nav2's
    ``pf_err``): smaller keeps more particles."""
    kld_z: Positive = 0.99
    """KLD sampling's normal quantile (nav2's ``pf_z``; used as the quantile itself, as nav2 does)."""
    alpha1: NonNegative = 0.02
    """Rotation noise from rotation (nav2's ``alpha1``, the ``diff`` model): the variance of a turn's
    error per rad² turned."""
    alpha2: Annotated[NonNegative, msgspec.Meta(extra={"unit": "rad²/m²"})] = 0.005
    """Rotation noise from translation (nav2's ``alpha2``): a turn's error variance per m² driven."""
    alpha3: NonNegative = 0.02
    """Translation noise from translation (nav2's ``alpha3``): the variance of the distance's error
    per m² driven."""
    alpha4: Annotated[NonNegative, msgspec.Meta(extra={"unit": "m²/rad²"})] = 0.005
    """Translation noise from rotation (nav2's ``alpha4``): the distance's error variance per rad² turned."""
    beams: Annotated[int, msgspec.Meta(ge=1, le=10_000)] = 60
    """Rays of each scan the filter weighs, evenly spaced over the scan (nav2's ``max_beams``)."""
    z_hit: Probability = 0.9
    """Weight of the Gaussian about the nearest obstacle in a ray's likelihood (nav2's ``z_hit``)."""
    z_rand: Probability = 0.1
    """Weight of the uniform over the range in a ray's likelihood (nav2's ``z_rand``): what keeps a
    ray that hits something not on the map (a person, another robot) from ruling a particle out."""
    sigma_hit: Annotated[Positive, METRES] = 0.1
    """Standard deviation of a ray's endpoint about the nearest obstacle (nav2's ``sigma_hit``): the
    lidar's noise and the map's cells together, and how far off a particle still finds its way
    (0.05 tracks as well but recovers less)."""
    likelihood_max_dist: Annotated[Positive, METRES] = 2.0
    """How far from an obstacle the likelihood field is computed, beyond it capped (nav2's
    ``laser_likelihood_max_dist``)."""
    update_min_d: Annotated[NonNegative, METRES] = 0.05
    """The filter updates after the odometry has moved this far since its last update (nav2's
    ``update_min_d``), or turned ``update_min_a``."""
    update_min_a: Annotated[NonNegative, RADIANS] = 0.05
    """Or turned this far (nav2's ``update_min_a``)."""
    resample_interval: Annotated[int, msgspec.Meta(ge=1)] = 1
    """Filter updates between resamplings (nav2's ``resample_interval``)."""
    recovery_alpha_slow: Rate = 0.001
    """The slow average of the scans' fit follows each update by this fraction (nav2's
    ``recovery_alpha_slow``); random particles are added while the fast average is below the slow. 0
    (either): none added."""
    recovery_alpha_fast: Rate = 0.1
    """The fast average's fraction (nav2's ``recovery_alpha_fast``); above ``recovery_alpha_slow``."""
    initial_sigma_xy: Annotated[NonNegative, METRES] = 0.25
    """Standard deviation of a seed's particles in x and in y when the seed gives no covariance
    (nav2's ``initial_cov_xx`` and ``initial_cov_yy`` are its square)."""
    initial_sigma_theta: Annotated[NonNegative, RADIANS] = 0.2
    """Standard deviation of a seed's headings when it gives no covariance."""
    max_jump: Annotated[Positive, METRES] = 0.1
    """An update that moves the estimate this much further than the odometry moved is counted as a
    jump (a converged estimate, not the first update after a seed)."""
    max_jump_angle: Annotated[Positive, RADIANS] = 0.1
    """Or turns it this much further than the odometry turned."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_particles > self.max_particles:
            raise ValueError(
                f"`min_particles` = {self.min_particles} must not exceed `max_particles` = {self.max_particles}"
            )
        if self.z_hit + self.z_rand <= 0.0:
            raise ValueError("`z_hit` and `z_rand` are both 0: a ray would weigh nothing")
        if (
            self.recovery_alpha_slow
            and self.recovery_alpha_fast
            and self.recovery_alpha_fast <= self.recovery_alpha_slow
        ):
            raise ValueError(
                f"`recovery_alpha_fast` = {self.recovery_alpha_fast} must exceed `recovery_alpha_slow` = "
                f"{self.recovery_alpha_slow} (or either be 0: no random particles)"
            )
