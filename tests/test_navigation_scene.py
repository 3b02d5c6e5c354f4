"""The drive's navigation in Foxglove (services/recording/navigation_scene.py through scene.py): the
map (``drive/map``) and the costmap (``drive/costmap``) as ``foxglove.Grid`` on ``/map`` and
``/costmap``, the running goal's plan (``drive/plan``) as the scene's ``plan`` line; fed stand-in
messages (no drive). The pure conversion read back through Foxglove's own compiled schemas, its
cost on a 400 x 400 costmap; ``run.mcap`` of journals holding those keys read back with the
``mcap`` reader (tests/test_navigation_scene_live.py: a real view and recorder)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.Grid_pb2 import Grid
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader

from schemas.codec import BadInput, decode, encode
from schemas.keys import Keys, Service
from schemas.messages import MAX_PATH_POINTS, PlannedPath, Time, TimedDoubleSeq
from schemas.navigation import GoalPlan, OccupancyGrid
from schemas.topics import Topic
from services.config import Config, load_config
from services.navigation.grid import GridGeometry
from services.recording.navigation_scene import (
    COSTMAP_FIELD,
    COSTMAP_PERIOD_NS,
    COSTMAP_TOPIC,
    COSTMAP_Z,
    GRID_UNKNOWN,
    MAP_FIELD,
    MAP_PERIOD_NS,
    MAP_TOPIC,
    MAP_Z,
    PLAN_POINTS,
)
from services.recording.record import SceneBuilder, Sink, write_run_recording
from services.recording.scene import PLAN_COLOR, SCENE_TOPIC, WORLD_FRAME, Scene
from services.runtime.journal import Journal, journal_path
from services.runtime.logs import BadInputCounter

CONFIG = Config()
KEYS = Keys()
MS = 1_000_000
S = 1_000_000_000


def _stamp(ns: int) -> Time:
    return Time.from_nanoseconds(ns)


def body_pose(stamp_ns: int, x: float = 0.0) -> TimedDoubleSeq:
    return TimedDoubleSeq(_stamp(stamp_ns), [x, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])


def occupancy(stamp_ns: int, geometry: GridGeometry, cells: np.ndarray) -> OccupancyGrid:
    """``cells`` (``[row, col]``, int8) as the drive publishes them, on ``geometry``."""
    return OccupancyGrid(
        tm=_stamp(stamp_ns),
        resolution=geometry.resolution,
        width=geometry.width,
        height=geometry.height,
        origin_x=geometry.origin_x,
        origin_y=geometry.origin_y,
        data=cells.astype(np.int8).tobytes(),
    )


GEOMETRY = GridGeometry(resolution=0.1, width=5, height=3, origin_x=-1.5, origin_y=2.25)
"""A grid wider than high, its corner off the origin: rows and columns cannot be mistaken."""


def _cells() -> np.ndarray:
    """Every cell a different value, unknown among them: row r, column c holds 10·r + c, but (2, 4): -1."""
    cells = np.array([[10 * row + col for col in range(GEOMETRY.width)] for row in range(GEOMETRY.height)])
    cells[2, 4] = -1
    return cells.astype(np.int8)


def _grid(shown: list[tuple[str, Any]], topic: str) -> Grid:
    (grid,) = [Grid.FromString(message.encode()) for shown_topic, message in shown if shown_topic == topic]
    return grid


def _scene_of(shown: list[tuple[str, Any]]) -> SceneUpdate | None:
    updates = [message for topic, message in shown if topic == SCENE_TOPIC]
    return SceneUpdate.FromString(updates[-1].encode()) if updates else None


def _entity(update: SceneUpdate, entity_id: str) -> Any:
    (entity,) = [entity for entity in update.entities if entity.id == entity_id]
    return entity


def _cell_corner(grid: Grid, index: int) -> tuple[float, float]:
    """Where Foxglove puts the corner nearest the grid's origin of the cell at byte ``index`` of
    ``data`` (foxglove.Grid's documented layout: y from the row, x from the cell in the row)."""
    row, offset = divmod(index, grid.row_stride)
    return (
        grid.pose.position.x + offset // grid.cell_stride * grid.cell_size.x,
        grid.pose.position.y + row * grid.cell_size.y,
    )


@pytest.mark.parametrize(
    ("topic", "shown_topic", "field_name", "z"),
    [(Topic.DRIVE_MAP, MAP_TOPIC, MAP_FIELD, MAP_Z), (Topic.DRIVE_COSTMAP, COSTMAP_TOPIC, COSTMAP_FIELD, COSTMAP_Z)],
)
def test_a_grid_is_the_messages_cells_at_its_origin_and_cell_size_in_the_world_frame(topic, shown_topic, field_name, z):
    scene = Scene(CONFIG.robot, CONFIG.sim)
    message = occupancy(3 * S, GEOMETRY, _cells())

    grid = _grid(scene.add(topic, message), shown_topic)

    assert grid.frame_id == WORLD_FRAME, "the frame of the scene's other world-frame entities"
    assert (grid.timestamp.seconds, grid.timestamp.nanos) == (3, 0)
    position, orientation = grid.pose.position, grid.pose.orientation
    assert (position.x, position.y, position.z) == (-1.5, 2.25, z)
    assert (orientation.x, orientation.y, orientation.z, orientation.w) == (0.0, 0.0, 0.0, 1.0)
    assert (grid.cell_size.x, grid.cell_size.y) == (0.1, 0.1)
    assert (grid.column_count, grid.row_stride, grid.cell_stride) == (5, 5, 1)
    assert len(grid.data) // grid.row_stride == 3, "three rows"
    assert list(grid.fields) == [PackedElementField(name=field_name, offset=0, type=PackedElementField.INT8)]
    shown = np.frombuffer(grid.data, dtype=np.int8).reshape(GEOMETRY.shape)
    expected = _cells()
    expected[2, 4] = GRID_UNKNOWN
    assert (shown == expected).all(), "every cell as published, row-major from the lowest y; unknown -128"


def test_each_cell_lies_where_the_navigation_puts_it():
    """Row order: the cell that holds a point on the drive's grid (services/navigation/grid.py) is
    the cell Foxglove draws around that point."""
    for x, y in [(-1.45, 2.26), (-1.05, 2.26), (-1.45, 2.5), (-1.01, 2.54), (-1.2, 2.4)]:
        col, row = GEOMETRY.cell(x, y)
        cells = np.zeros(GEOMETRY.shape, dtype=np.int8)
        cells[row, col] = 100
        grid = _grid(Scene(CONFIG.robot, CONFIG.sim).add(Topic.DRIVE_MAP, occupancy(0, GEOMETRY, cells)), MAP_TOPIC)
        (index,) = np.flatnonzero(np.frombuffer(grid.data, dtype=np.int8) == 100)
        corner_x, corner_y = _cell_corner(grid, int(index))
        assert corner_x <= x < corner_x + grid.cell_size.x and corner_y <= y < corner_y + grid.cell_size.y, (x, y)


def test_every_occupancy_value_is_shown_as_it_is_but_unknown():
    values = np.array([[*range(-1, 101), 0, 0]], dtype=np.int8).reshape(8, 13)
    geometry = GridGeometry(0.05, 13, 8, 0.0, 0.0)
    grid = _grid(
        Scene(CONFIG.robot, CONFIG.sim).add(Topic.DRIVE_COSTMAP, occupancy(0, geometry, values)), COSTMAP_TOPIC
    )
    shown = np.frombuffer(grid.data, dtype=np.int8).reshape(8, 13)
    assert (shown == np.where(values == -1, GRID_UNKNOWN, values)).all()
    assert GRID_UNKNOWN < -25, "below the Value min docs/recording.md gives the 3D panel, apart from free (0)"


def test_the_costmap_is_shown_as_it_comes_at_most_every_half_second():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    geometry = GridGeometry(0.05, 4, 4, 0.0, 0.0)
    cells = np.zeros(geometry.shape, dtype=np.int8)
    shown_at = [
        stamp_ns
        for stamp_ns in (S, S + 200 * MS, S + COSTMAP_PERIOD_NS, 2 * S, 3 * S, 100 * MS)
        if scene.add(Topic.DRIVE_COSTMAP, occupancy(stamp_ns, geometry, cells))
    ]
    assert shown_at == [S, S + COSTMAP_PERIOD_NS, 2 * S, 3 * S, 100 * MS], "one earlier: a restarted clock, shown"


def test_the_map_comes_once_and_is_shown_at_once_then_again_every_five_seconds():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    message = occupancy(S, GEOMETRY, _cells())
    assert [topic for topic, _ in scene.add(Topic.DRIVE_MAP, message)] == [MAP_TOPIC]
    again = []
    for stamp_ns in range(S, 12 * S, 100 * MS):
        for topic, grid in scene.add(Topic.SIM_BODY_POSE, body_pose(stamp_ns)):
            if topic == MAP_TOPIC:
                again.append(stamp_ns)
                decoded = Grid.FromString(grid.encode())
                assert decoded.data == _grid([(topic, grid)], MAP_TOPIC).data
                assert decoded.timestamp.seconds * S + decoded.timestamp.nanos == stamp_ns, "stamped when sent"
    assert again == [S + MAP_PERIOD_NS, S + 2 * MAP_PERIOD_NS]


def test_a_map_that_comes_late_with_an_old_stamp_is_sent_again_with_the_next_ground_truth():
    """A view started mid-run gets the latched map stamped at the run's start."""
    scene = Scene(CONFIG.robot, CONFIG.sim)
    scene.add(Topic.SIM_BODY_POSE, body_pose(60 * S))
    assert scene.add(Topic.DRIVE_MAP, occupancy(0, GEOMETRY, _cells()))
    assert MAP_TOPIC in [topic for topic, _ in scene.add(Topic.SIM_BODY_POSE, body_pose(60 * S + 20 * MS))]


def _plan(stamp_ns: int, points: list[tuple[float, float]], goal_id: str = "g1") -> GoalPlan:
    return GoalPlan(tm=_stamp(stamp_ns), goal_id=goal_id, points=points)


def test_the_plan_is_a_line_through_its_points_as_the_planned_path_is_drawn_in_its_own_colour():
    points = [(0.0, 0.0), (0.5, 0.1), (1.0, 0.4), (1.2, 1.5)]
    scene = Scene(CONFIG.robot, CONFIG.sim)
    scene.add(Topic.SIM_BODY_POSE, body_pose(0))
    scene.add(Topic.DRIVE_PATH, PlannedPath(tm=_stamp(0), scenario="square", points=points))
    assert scene.add(Topic.DRIVE_PLAN, _plan(S, points)) == [], "drawn at the next scene update"
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(S + 20 * MS)))
    assert update is not None, "a new plan brings a scene update at once"

    plan, path = _entity(update, "plan"), _entity(update, "planned_path")
    assert plan.frame_id == WORLD_FRAME
    (line,) = plan.lines
    assert [(p.x, p.y) for p in line.points] == points
    (path_line,) = path.lines
    assert [p.z for p in line.points] == [p.z for p in path_line.points], "on the ground as the path"
    assert (line.type, line.thickness, line.pose) == (path_line.type, path_line.thickness, path_line.pose)
    assert line.color == Color.FromString(PLAN_COLOR.encode()) and line.color != path_line.color, "its own colour"


def test_an_empty_plan_clears_it_and_a_new_one_replaces_it():
    scene = Scene(CONFIG.robot, CONFIG.sim)
    scene.add(Topic.DRIVE_PLAN, _plan(0, [(0.0, 0.0), (1.0, 0.0)]))
    scene.add(Topic.DRIVE_PLAN, _plan(S, [(0.0, 0.0), (0.0, 2.0), (1.0, 2.0)]))
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(S)))
    assert update is not None
    assert [(p.x, p.y) for p in _entity(update, "plan").lines[0].points] == [(0.0, 0.0), (0.0, 2.0), (1.0, 2.0)]

    scene.add(Topic.DRIVE_PLAN, _plan(2 * S, []))
    cleared = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(2 * S + 20 * MS)))
    assert cleared is not None, "the goal's end brings a scene update at once"
    plan = _entity(cleared, "plan")
    assert plan.frame_id == WORLD_FRAME and not plan.lines, "the entity stays, empty: a seek back shows none"


def test_before_any_plan_the_plan_entity_is_there_and_empty():
    update = _scene_of(Scene(CONFIG.robot, CONFIG.sim).add(Topic.SIM_BODY_POSE, body_pose(0)))
    assert update is not None and not _entity(update, "plan").lines


def test_a_long_plan_is_drawn_through_a_bounded_number_of_its_points_its_ends_kept():
    points = [(0.01 * i, 0.02 * i) for i in range(MAX_PATH_POINTS)]
    scene = Scene(CONFIG.robot, CONFIG.sim)
    scene.add(Topic.DRIVE_PLAN, _plan(0, points))
    update = _scene_of(scene.add(Topic.SIM_BODY_POSE, body_pose(0)))
    assert update is not None
    drawn = [(p.x, p.y) for p in _entity(update, "plan").lines[0].points]
    assert len(drawn) == PLAN_POINTS and drawn[0] == points[0] and drawn[-1] == points[-1]
    assert set(drawn) <= set(points) and drawn == sorted(drawn), "its own points, in order"
    assert len(update.SerializeToString()) < 20_000, "a plan adds at most about 15 kB to a scene update"


def test_a_fleets_grids_and_plans_are_each_robots_own():
    fleet = [load_config(overrides={"robot.name": name}) for name in ("rh0", "rh1")]
    shown: list[tuple[str, Any]] = []
    builder = SceneBuilder(
        fleet[0], Sink(lambda *_: None, lambda topic, message, *_: shown.append((topic, message))), fleet
    )
    rh1 = Keys("rh1")
    builder.take(rh1.drive_map, encode(occupancy(0, GEOMETRY, _cells())), 0)
    builder.take(rh1.drive_costmap, encode(occupancy(0, GEOMETRY, _cells())), 0)
    builder.take(rh1.drive_plan, encode(_plan(0, [(0.0, 0.0), (1.0, 1.0)])), 0)
    builder.take(rh1.sim_body_pose, encode(body_pose(MS)), 0)
    assert {"/rh1/map", "/rh1/costmap"} <= {topic for topic, _ in shown}
    update = _scene_of(shown)
    assert update is not None and len(_entity(update, "rh1/plan").lines) == 1
    assert "plan" not in {entity.id for entity in update.entities}, "no robot's plan is unnamed"


def test_a_grid_no_drive_publishes_is_dropped_by_the_view_and_kept_undrawn_by_a_recorder():
    good = encode(occupancy(0, GEOMETRY, _cells()))
    bad = good.replace(b'"width":5', b'"width":4')
    with pytest.raises(BadInput):
        decode(OccupancyGrid, bad)
    counter = BadInputCounter("view")
    samples: list[str] = []
    drawn: list[str] = []
    sink = Sink(lambda key, *_: samples.append(key), lambda topic, *_: drawn.append(topic))
    SceneBuilder(CONFIG, sink, bad_input=counter).take(KEYS.drive_map, bad, 0)
    assert samples == [] and drawn == [] and counter.status().by_key[KEYS.drive_map].count == 1
    SceneBuilder(CONFIG, sink).take(KEYS.drive_map, bad, 0)
    assert samples == [KEYS.drive_map] and drawn == [], "the recording is the evidence"


def _costmap(stamp_ns: int, side: int) -> OccupancyGrid:
    """A costmap as the drive's could be: unknown beyond what was seen, free, inflated, lethal."""
    rng = np.random.default_rng(51)
    cells = rng.integers(-1, 101, size=(side, side)).astype(np.int8)
    return occupancy(stamp_ns, GridGeometry.centred(0.0, 0.0, side * 0.05, 0.05), cells)


def test_run_mcap_keeps_the_navigation_keys_as_published_and_draws_them(tmp_path):
    """``invent up``'s recording, of the services' journals: the raw samples of ``drive/map``,
    ``drive/costmap`` and ``drive/plan`` on their keys with their types' schemas, ``/map`` and
    ``/costmap`` as ``foxglove.Grid``, the plan in ``/scene``; read back with the mcap reader."""
    journals = tmp_path / "journals"
    journals.mkdir()
    sim, drive = (Journal(journal_path(journals, str(service))) for service in (Service.SIM, Service.DRIVE))
    published_ns = 1_800_000_000 * S
    published: dict[str, list[bytes]] = {}

    def publish(journal: Journal, key: str, payload: bytes, stamp_ns: int) -> None:
        journal.write(key, payload, published_ns + stamp_ns)
        published.setdefault(key, []).append(payload)

    publish(drive, KEYS.drive_map, encode(occupancy(0, GEOMETRY, _cells())), 0)
    for step in range(60):
        stamp_ns = step * 100 * MS
        publish(sim, KEYS.sim_body_pose, encode(body_pose(stamp_ns, 0.01 * step)), stamp_ns)
        if step % 10 == 5:
            publish(drive, KEYS.drive_costmap, encode(_costmap(stamp_ns, 40)), stamp_ns)
        if step == 12:
            publish(drive, KEYS.drive_plan, encode(_plan(stamp_ns, [(0.0, 0.0), (1.0, 0.5), (2.0, 0.5)])), stamp_ns)
        if step == 30:
            publish(drive, KEYS.drive_plan, encode(_plan(stamp_ns, [])), stamp_ns)
    sim.close()
    drive.close()
    output = tmp_path / "run.mcap"

    assert write_run_recording(journals, output, load_config(None, {})).cut_short == []

    with output.open("rb") as file:
        reader = make_reader(file)
        channels = {
            channel.topic: reader.get_summary().schemas[channel.schema_id]
            for channel in reader.get_summary().channels.values()
        }
        recorded: dict[str, list[tuple[int, bytes]]] = {}
        for _schema, channel, message in reader.iter_messages():
            recorded.setdefault(channel.topic, []).append((message.publish_time, message.data))
    for key, type_name in (
        (KEYS.drive_map, "OccupancyGrid"),
        (KEYS.drive_costmap, "OccupancyGrid"),
        (KEYS.drive_plan, "GoalPlan"),
    ):
        assert channels[key].name == type_name and channels[key].encoding == "jsonschema"
        assert [data for _t, data in recorded[key]] == published[key], f"{key}: every sample, as published"
    for topic in (MAP_TOPIC, COSTMAP_TOPIC):
        assert channels[topic].name == "foxglove.Grid" and channels[topic].encoding == "protobuf"
    maps = [(stamp, Grid.FromString(data)) for stamp, data in recorded[MAP_TOPIC]]
    assert [stamp for stamp, _ in maps] == [0, MAP_PERIOD_NS], "at once, then again five seconds on"
    assert all(grid.column_count == 5 and len(grid.data) == 15 for _, grid in maps)
    costmaps = [Grid.FromString(data) for _stamp, data in recorded[COSTMAP_TOPIC]]
    assert len(costmaps) == 6 and all(grid.column_count == 40 for grid in costmaps)
    plans = [
        [(p.x, p.y) for line in _entity(SceneUpdate.FromString(data), "plan").lines for p in line.points]
        for _stamp, data in recorded[SCENE_TOPIC]
    ]
    assert [(0.0, 0.0), (1.0, 0.5), (2.0, 0.5)] in plans, "the plan drawn"
    assert plans[-1] == [], "cleared by the empty plan"
