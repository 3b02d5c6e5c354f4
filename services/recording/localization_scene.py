"""The particle filter in Foxglove (docs/recording.md, "Localization"), pure (no zenoh):
:class:`LocalizationDrawing` takes ``localization/pose`` (``TimedPosition``) and
``localization/particles`` (``ParticleCloud``) and gives what :class:`services.recording.scene.Scene`
shows of them, each a ``foxglove.SceneUpdate`` of one entity in the world frame (the ``map``
frame's coordinates, as every world-frame entity of the scene), on a topic of its own:

- ``/localization/particles``, entity ``particles``: each particle a short tick on the ground from
  its position along its heading (:data:`PARTICLE_LENGTH_M`; one ``LINE_LIST``), at most
  :data:`PARTICLES_DRAWN` of them, evenly spread over the cloud (its order is the filter's, no
  ranking: a uniform sample), one update per ``localization/particles``;
- ``/localization/covariance``, entity ``covariance``: the estimate's uncertainty, one update per
  ``localization/pose`` that carries a covariance (``error``: xx, xy, xθ, yy, yθ, θθ; the particle
  filter's): the 2σ ellipse of its x, y block (a ``LINE_LOOP`` of :data:`ELLIPSE_POINTS` points,
  its semi-axes twice the square roots of the block's eigenvalues along their eigenvectors) and the
  heading's ±2σ as a wedge (a ``LINE_STRIP`` from the estimate out :data:`WEDGE_LENGTH_M` at
  θ − 2σθ, along an arc to θ + 2σθ and back; a spread of π or more is the whole circle). A pose
  without one (the stub's) draws none: if an ellipse was drawn, one update with the entity empty
  takes it away.

Each update carries its whole entity, so a viewer that seeks or joins late needs only the last one
of each topic; neither is in the ``/scene`` updates, which come every half second whether or not
the particles changed. A cloud of :data:`PARTICLES_DRAWN` ticks is about 60 kB
(tests/test_localization_scene.py measures it), once per ``localization.particles_rate``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from foxglove.messages import (
    Color,
    LinePrimitive,
    LinePrimitiveLineType,
    SceneEntity,
    SceneUpdate,
    Timestamp,
)

from schemas.codec import BadInput
from schemas.messages import Time, TimedPosition
from schemas.navigation import COVARIANCE_LENGTH, ParticleCloud
from services.recording.scene_shapes import ground_line

PARTICLES_TOPIC = "/localization/particles"
COVARIANCE_TOPIC = "/localization/covariance"
PARTICLES_DRAWN = 1000
"""The most particles drawn of a cloud (``localization/particles`` carries up to 20,000)."""
PARTICLE_LENGTH_M = 0.06
"""A particle's tick, from its position along its heading."""
SIGMAS = 2.0
"""The ellipse and the wedge are drawn this many standard deviations out."""
ELLIPSE_POINTS = 48
WEDGE_LENGTH_M = 0.4
WEDGE_ARC_POINTS = 16
PARTICLES_Z = 0.012
COVARIANCE_Z = 0.015
"""Heights over the ground: above the grids and the paths (5 mm), beside the trails (1 cm)."""
PARTICLES_COLOR = Color(r=1.0, g=0.55, b=0.0, a=0.7)
COVARIANCE_COLOR = Color(r=0.95, g=0.1, b=0.6, a=1.0)

Shown = list[tuple[str, SceneUpdate]]


def covariance_matrix(values: list[float]) -> np.ndarray:
    """The symmetric 3 × 3 covariance over (x, y, θ) of its upper triangle (xx, xy, xθ, yy, yθ, θθ);
    BadInput for another number of values."""
    if len(values) != COVARIANCE_LENGTH:
        raise BadInput(f"a covariance of {len(values)} values, not {COVARIANCE_LENGTH}")
    xx, xy, xt, yy, yt, tt = values
    return np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]], dtype=np.float64)


def ellipse_axes(covariance: np.ndarray) -> tuple[float, float, float]:
    """(major, minor, angle) of the :data:`SIGMAS` ellipse of the x, y block: the semi-axes
    ``SIGMAS * sqrt(eigenvalue)`` (a negative eigenvalue, rounding's, taken as 0) and the major
    axis's direction from x, in radians."""
    values, vectors = np.linalg.eigh(covariance[:2, :2])
    minor, major = (SIGMAS * math.sqrt(max(float(value), 0.0)) for value in values)
    return major, minor, math.atan2(float(vectors[1, 1]), float(vectors[0, 1]))


def ellipse_points(x: float, y: float, covariance: np.ndarray) -> list[tuple[float, float]]:
    """:data:`ELLIPSE_POINTS` points around the ellipse of :func:`ellipse_axes`, centred on (x, y)."""
    major, minor, angle = ellipse_axes(covariance)
    cos, sin = math.cos(angle), math.sin(angle)
    points = []
    for index in range(ELLIPSE_POINTS):
        phi = 2.0 * math.pi * index / ELLIPSE_POINTS
        u, v = major * math.cos(phi), minor * math.sin(phi)
        points.append((x + cos * u - sin * v, y + sin * u + cos * v))
    return points


def wedge_points(x: float, y: float, theta: float, variance: float) -> list[tuple[float, float]]:
    """The heading's ±:data:`SIGMAS` σ wedge: from (x, y) out :data:`WEDGE_LENGTH_M` at θ − 2σ, along
    the arc to θ + 2σ, and back (a spread of π or more: the whole circle)."""
    spread = min(SIGMAS * math.sqrt(max(variance, 0.0)), math.pi)
    arc = [theta - spread + 2.0 * spread * index / (WEDGE_ARC_POINTS - 1) for index in range(WEDGE_ARC_POINTS)]
    edge = [(x + WEDGE_LENGTH_M * math.cos(a), y + WEDGE_LENGTH_M * math.sin(a)) for a in arc]
    return [(x, y), *edge, (x, y)]


def drawn_particles(count: int) -> range | list[int]:
    """The indices of a cloud's particles drawn: all up to :data:`PARTICLES_DRAWN`, else that many
    evenly spread."""
    if count <= PARTICLES_DRAWN:
        return range(count)
    return [index * count // PARTICLES_DRAWN for index in range(PARTICLES_DRAWN)]


class LocalizationDrawing:
    """The particles and the estimate's covariance of one robot; ``topics``: the robot's topics by
    :data:`PARTICLES_TOPIC` and :data:`COVARIANCE_TOPIC` (``/<robot>/localization/particles`` in a
    fleet), ``ids``: its entities' ids by ``particles`` and ``covariance``; ``frame``: the world
    frame; ``stamp``: a message's ``Time`` as a Foxglove ``Timestamp``."""

    def __init__(
        self, topics: dict[str, str], ids: dict[str, str], frame: str, stamp: Callable[[Time], Timestamp]
    ) -> None:
        self._topics = topics
        self._ids = ids
        self._frame = frame
        self._stamp = stamp
        self.covariance_shown = False

    def pose(self, message: TimedPosition) -> Shown:
        """A ``localization/pose``: its ellipse and wedge if it carries a covariance; else none (an
        empty entity if one was shown). BadInput for an ``error`` neither empty nor a covariance."""
        if not message.error:
            if not self.covariance_shown:
                return []
            self.covariance_shown = False
            return [self._update(COVARIANCE_TOPIC, "covariance", message.tm, [])]
        covariance = covariance_matrix(message.error)
        lines = [
            ground_line(
                ellipse_points(message.x, message.y, covariance),
                COVARIANCE_COLOR,
                0.01,
                COVARIANCE_Z,
                LinePrimitiveLineType.LineLoop,
            ),
            ground_line(
                wedge_points(message.x, message.y, message.theta, float(covariance[2, 2])),
                COVARIANCE_COLOR,
                0.01,
                COVARIANCE_Z,
            ),
        ]
        self.covariance_shown = True
        return [self._update(COVARIANCE_TOPIC, "covariance", message.tm, lines)]

    def particles(self, cloud: ParticleCloud) -> Shown:
        """A ``localization/particles``: a tick per particle drawn (none for an empty cloud)."""
        points: list[tuple[float, float]] = []
        for index in drawn_particles(len(cloud.x)):
            x, y, theta = cloud.x[index], cloud.y[index], cloud.theta[index]
            points += [(x, y), (x + PARTICLE_LENGTH_M * math.cos(theta), y + PARTICLE_LENGTH_M * math.sin(theta))]
        lines = (
            [ground_line(points, PARTICLES_COLOR, 0.005, PARTICLES_Z, LinePrimitiveLineType.LineList)] if points else []
        )
        return [self._update(PARTICLES_TOPIC, "particles", cloud.tm, lines)]

    def _update(self, topic: str, entity: str, tm: Time, lines: list[LinePrimitive]) -> tuple[str, SceneUpdate]:
        scene_entity = SceneEntity(timestamp=self._stamp(tm), frame_id=self._frame, id=self._ids[entity], lines=lines)
        return self._topics[topic], SceneUpdate(entities=[scene_entity])
