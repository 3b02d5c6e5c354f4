"""The particle filter in Foxglove (services/recording/localization_scene.py through scene.py and the
recorder's SceneBuilder), pure: a ``localization/pose`` with a covariance drawn as its 2σ ellipse and
heading wedge on ``/localization/covariance``, a stub's pose (no covariance) drawing none, the
particles (``localization/particles``) as ticks on ``/localization/particles``; each read back
through Foxglove's own compiled schemas."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from schemas.codec import BadInput, encode
from schemas.keys import Keys
from schemas.messages import Time, TimedPosition
from schemas.navigation import ParticleCloud
from schemas.topics import Topic
from services.config import Config, load_config
from services.recording.localization_scene import (
    COVARIANCE_TOPIC,
    ELLIPSE_POINTS,
    PARTICLE_LENGTH_M,
    PARTICLES_DRAWN,
    PARTICLES_TOPIC,
    SIGMAS,
    WEDGE_LENGTH_M,
    ellipse_axes,
)
from services.recording.record import SceneBuilder, Sink
from services.recording.scene import LOCALIZATION_TOPIC, WORLD_FRAME, Scene

CONFIG = Config()
S = 1_000_000_000


def _pose(stamp_ns: int, x: float, y: float, theta: float, error: list[float]) -> TimedPosition:
    return TimedPosition(tm=Time.from_nanoseconds(stamp_ns), id=[], x=x, y=y, theta=theta, error=error)


def _rotated(sigma_major: float, sigma_minor: float, angle: float, var_theta: float) -> tuple[np.ndarray, list[float]]:
    """A covariance whose x, y block has standard deviations ``sigma_major`` along ``angle`` and
    ``sigma_minor`` across: the 2 × 2 block and the six values ``localization/pose`` carries."""
    turn = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    block = turn @ np.diag([sigma_major**2, sigma_minor**2]) @ turn.T
    return block, [float(block[0, 0]), float(block[0, 1]), 0.001, float(block[1, 1]), -0.002, var_theta]


def _updates(shown: list[tuple[str, Any]], topic: str) -> list[SceneUpdate]:
    return [SceneUpdate.FromString(message.encode()) for shown_topic, message in shown if shown_topic == topic]


def _points(line: Any) -> np.ndarray:
    return np.array([(p.x, p.y) for p in line.points])


def test_the_ellipse_is_the_2_sigma_contour_of_the_xy_block_along_its_eigenvectors():
    block, values = _rotated(0.3, 0.1, math.radians(30), 0.04)
    scene = Scene(CONFIG.robot, CONFIG.sim)
    shown = scene.add(Topic.LOCALIZATION_POSE, _pose(2 * S, 1.0, -2.0, 0.5, values))
    (pose,) = [PoseInFrame.FromString(m.encode()) for t, m in shown if t == LOCALIZATION_TOPIC]
    assert (pose.pose.position.x, pose.pose.position.y) == (1.0, -2.0), "the estimate's pose as before"
    ((entity,),) = [update.entities for update in _updates(shown, COVARIANCE_TOPIC)]
    assert (entity.id, entity.frame_id, entity.timestamp.seconds) == ("covariance", WORLD_FRAME, 2)
    ellipse, wedge = entity.lines
    assert ellipse.type == LinePrimitive.LINE_LOOP and len(ellipse.points) == ELLIPSE_POINTS
    offsets = _points(ellipse) - (1.0, -2.0)
    mahalanobis = np.einsum("ij,jk,ik->i", offsets, np.linalg.inv(block), offsets)
    assert mahalanobis == pytest.approx(np.full(ELLIPSE_POINTS, SIGMAS**2)), "every point 2σ out"
    distances = np.hypot(offsets[:, 0], offsets[:, 1])
    assert distances.max() == pytest.approx(0.6) and distances.min() == pytest.approx(0.2, abs=1e-3)
    farthest = offsets[np.argmax(distances)]
    assert math.atan2(farthest[1], farthest[0]) % math.pi == pytest.approx(math.radians(30)), "along the major axis"
    major, minor, angle = ellipse_axes(np.pad(block, ((0, 1), (0, 1))))
    assert (major, minor, angle % math.pi) == pytest.approx((0.6, 0.2, math.radians(30)))
    assert wedge.type == LinePrimitive.LINE_STRIP
    edge = _points(wedge)
    assert edge[0] == pytest.approx((1.0, -2.0)) and edge[-1] == pytest.approx((1.0, -2.0)), "from and back to it"
    rim = edge[1:-1] - (1.0, -2.0)
    assert np.hypot(rim[:, 0], rim[:, 1]) == pytest.approx(np.full(len(rim), WEDGE_LENGTH_M))
    headings = np.arctan2(rim[:, 1], rim[:, 0])
    assert (headings[0], headings[-1]) == pytest.approx((0.5 - 2 * 0.2, 0.5 + 2 * 0.2)), "θ ± 2σθ"
    assert entity.lines[0].points[0].z > 0.01, "above the grids, the paths and the trails"


def test_a_pose_without_a_covariance_draws_no_ellipse_and_takes_a_drawn_one_away():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    stub = scene.add(Topic.LOCALIZATION_POSE, _pose(S, 0.0, 0.0, 0.0, []))
    assert [topic for topic, _ in stub] == [LOCALIZATION_TOPIC], "the stub's fix: its pose only"
    _block, values = _rotated(0.2, 0.2, 0.0, 0.01)
    assert _updates(scene.add(Topic.LOCALIZATION_POSE, _pose(2 * S, 0.0, 0.0, 0.0, values)), COVARIANCE_TOPIC)
    (cleared,) = _updates(scene.add(Topic.LOCALIZATION_POSE, _pose(3 * S, 0.0, 0.0, 0.0, [])), COVARIANCE_TOPIC)
    ((entity,),) = [cleared.entities]
    assert entity.id == "covariance" and len(entity.lines) == 0, "an empty entity: the ellipse goes away"
    assert not _updates(scene.add(Topic.LOCALIZATION_POSE, _pose(4 * S, 0.0, 0.0, 0.0, [])), COVARIANCE_TOPIC)
    with pytest.raises(BadInput, match="not 6"):
        scene.add(Topic.LOCALIZATION_POSE, _pose(5 * S, 0.0, 0.0, 0.0, [0.1, 0.2]))


def test_a_heading_spread_of_pi_or_more_is_the_whole_circle():
    _block, values = _rotated(0.1, 0.1, 0.0, 25.0)
    (update,) = _updates(
        Scene(CONFIG.robot, CONFIG.sim).add(Topic.LOCALIZATION_POSE, _pose(S, 0.0, 0.0, 1.0, values)), COVARIANCE_TOPIC
    )
    rim = _points(update.entities[0].lines[1])[1:-1]
    assert rim[0] == pytest.approx(rim[-1]) and rim[0] == pytest.approx(
        (-WEDGE_LENGTH_M * math.cos(1.0), -WEDGE_LENGTH_M * math.sin(1.0))
    )


def test_each_particle_is_a_tick_along_its_heading_in_the_world_frame():
    cloud = ParticleCloud(
        tm=Time.from_nanoseconds(4 * S), x=[0.0, 1.0, -1.0], y=[0.0, 2.0, 0.5], theta=[0.0, math.pi / 2, math.pi],
        weight=[0.2, 0.3, 0.5],
    )  # fmt: skip
    ((entity,),) = [
        u.entities
        for u in _updates(Scene(CONFIG.robot, CONFIG.sim).add(Topic.LOCALIZATION_PARTICLES, cloud), PARTICLES_TOPIC)
    ]
    assert (entity.id, entity.frame_id, entity.timestamp.seconds) == ("particles", WORLD_FRAME, 4)
    (ticks,) = entity.lines
    assert ticks.type == LinePrimitive.LINE_LIST
    length = PARTICLE_LENGTH_M
    assert _points(ticks) == pytest.approx(
        np.array([(0.0, 0.0), (length, 0.0), (1.0, 2.0), (1.0, 2.0 + length), (-1.0, 0.5), (-1.0 - length, 0.5)])
    )
    empty = ParticleCloud(tm=Time.from_nanoseconds(5 * S), x=[], y=[], theta=[], weight=[])
    ((entity,),) = [
        u.entities
        for u in _updates(Scene(CONFIG.robot, CONFIG.sim).add(Topic.LOCALIZATION_PARTICLES, empty), PARTICLES_TOPIC)
    ]
    assert len(entity.lines) == 0


def test_a_large_cloud_is_drawn_through_an_even_sample_and_costs_about_60_kb():
    count = 20_000
    rng = np.random.default_rng(1)
    cloud = ParticleCloud(
        tm=Time.from_nanoseconds(S),
        x=rng.normal(0.0, 1.0, count).tolist(),
        y=rng.normal(0.0, 1.0, count).tolist(),
        theta=rng.uniform(-math.pi, math.pi, count).tolist(),
        weight=[1.0 / count] * count,
    )
    (message,) = [
        m for t, m in Scene(CONFIG.robot, CONFIG.sim).add(Topic.LOCALIZATION_PARTICLES, cloud) if t == PARTICLES_TOPIC
    ]
    update = SceneUpdate.FromString(message.encode())
    points = _points(update.entities[0].lines[0])
    assert len(points) == 2 * PARTICLES_DRAWN
    assert points[0::2] == pytest.approx(
        np.array([(cloud.x[i], cloud.y[i]) for i in range(0, count, count // PARTICLES_DRAWN)])
    )
    assert len(message.encode()) < 70_000, len(message.encode())


def test_the_recorder_shows_a_fleet_robots_particles_and_ellipse_under_its_own_names():
    shown: list[tuple[str, Any]] = []
    sink = Sink(sample=lambda *_: None, shown=lambda topic, message, *_: shown.append((topic, message)))
    configs = [load_config(overrides={"robot.name": name}) for name in ("rh0", "rh1")]
    builder = SceneBuilder(configs[0], sink, fleet=configs)
    keys = Keys("rh1")
    _block, values = _rotated(0.2, 0.1, 0.3, 0.01)
    builder.take(keys.localization_pose, encode(_pose(S, 0.5, 0.5, 0.0, values)), 0)
    cloud = ParticleCloud(tm=Time.from_nanoseconds(S), x=[0.5], y=[0.5], theta=[0.0], weight=[1.0])
    builder.take(keys.localization_particles, encode(cloud), 0)
    by_topic = {
        topic: SceneUpdate.FromString(message.encode())
        for topic, message in shown
        if "localization/" in topic and topic != "/rh1/localization/pose"
    }
    assert set(by_topic) == {"/rh1/localization/covariance", "/rh1/localization/particles"}
    assert by_topic["/rh1/localization/covariance"].entities[0].id == "rh1/covariance"
    assert by_topic["/rh1/localization/particles"].entities[0].id == "rh1/particles"
