"""The drive's navigation in Foxglove (docs/recording.md, "Navigation"), pure (no zenoh):
:class:`NavigationDrawing` takes ``drive/map`` and ``drive/costmap`` (``OccupancyGrid``) and
``drive/plan`` (``GoalPlan``) and gives what :class:`services.recording.scene.Scene` shows of them:

- ``/map`` and ``/costmap`` (``foxglove.Grid``, in the world frame, the ``map`` frame's coordinates
  as every world-frame entity of the scene): one signed byte a cell (field ``occupancy`` on the
  map, ``cost`` on the costmap, ``INT8``), row-major from row 0, the lowest y, as the message has
  them, the grid's corner at (``origin_x``, ``origin_y``), ``resolution`` a cell's side. A cell
  is the message's value (0 free to 100 occupied or lethal) but for an unknown one:
  :data:`GRID_UNKNOWN` (-128), not -1, so that a colour scale sets it apart from a free cell (-1
  lies next to 0 on any scale; -128 lies below a ``Value min`` of -25, see docs/recording.md for
  the 3D panel's settings). The costmap lies :data:`COSTMAP_Z` above the ground, over the map;
- the running goal's plan (``drive/plan``), a line the scene draws as it draws the scenario's
  planned path, its points as they are up to :data:`PLAN_POINTS` (a longer plan is drawn through
  that many of them, evenly spread, its ends kept: every scene update carries it); an empty plan
  (the goal ended) draws none.

The map comes once (a latched key): it is shown at once and again every :data:`MAP_PERIOD_NS` of
simulation time (with the ground truth), so that a Foxglove client that connects to a live view
later has it within that time, as it has the scene's obstacles. The costmap is shown as it comes,
at most every :data:`COSTMAP_PERIOD_NS` (the drive publishes it about once a second; its key keeps
every one): converting a costmap of 400 × 400 cells costs about 0.2 ms, decoding its sample 0.3 ms
(tests/test_navigation_scene.py measures both).
"""

from __future__ import annotations

from collections.abc import Callable

from foxglove.messages import (
    Grid,
    PackedElementField,
    PackedElementFieldNumericType,
    Pose,
    Quaternion,
    Timestamp,
    Vector2,
    Vector3,
)

from schemas.messages import Time
from schemas.navigation import OccupancyGrid

MAP_TOPIC = "/map"
COSTMAP_TOPIC = "/costmap"
MAP_FIELD = "occupancy"
COSTMAP_FIELD = "cost"
GRID_UNKNOWN = -128
"""What an unknown cell (-1 in ``OccupancyGrid.data``) is in a shown grid."""
MAP_Z = 0.001
COSTMAP_Z = 0.002
"""Heights of the grids: on the ground, the costmap over the map, both under the paths (5 mm up)."""
MAP_PERIOD_NS = 5_000_000_000
"""The map is shown again this often (simulation time): a live client that connects later gets it."""
COSTMAP_PERIOD_NS = 500_000_000
"""The costmap is shown at most this often (simulation time), however often the drive publishes it."""
PLAN_POINTS = 500
"""The most points of a plan drawn (a trail's): 25 m at 5 cm a point, about 15 kB of every scene update."""

_SHOWN_CELLS = bytes(range(255)) + bytes([GRID_UNKNOWN & 0xFF])
"""``bytes.translate``'s table from a message's cells to a shown grid's: only -1 (the byte 255) changes."""

Shown = list[tuple[str, Grid]]


def shown_cells(message: OccupancyGrid) -> bytes:
    """The message's cells as a grid shows them: the same bytes, an unknown cell :data:`GRID_UNKNOWN`."""
    return message.data.translate(_SHOWN_CELLS)


def grid_message(message: OccupancyGrid, cells: bytes, field: str, frame: str, z: float, stamp: Timestamp) -> Grid:
    """A ``foxglove.Grid`` of ``message``'s geometry with ``cells`` (:func:`shown_cells`) as the
    ``INT8`` field ``field``, in ``frame``, ``z`` above its ground."""
    return Grid(
        timestamp=stamp,
        frame_id=frame,
        pose=Pose(
            position=Vector3(x=message.origin_x, y=message.origin_y, z=z),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        column_count=message.width,
        cell_size=Vector2(x=message.resolution, y=message.resolution),
        row_stride=message.width,
        cell_stride=1,
        fields=[PackedElementField(name=field, offset=0, type=PackedElementFieldNumericType.Int8)],
        data=cells,
    )


def drawn_plan(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The points of a plan drawn: all of them up to :data:`PLAN_POINTS`, else that many evenly
    spread along the list, the first and the last among them."""
    count = len(points)
    if count <= PLAN_POINTS:
        return list(points)
    return [points[round(i * (count - 1) / (PLAN_POINTS - 1))] for i in range(PLAN_POINTS)]


class NavigationDrawing:
    """The map, costmap and plan of one robot; ``topics``: the robot's ``/map`` and ``/costmap``
    topics (``/<robot>/map``, ... in a fleet), by :data:`MAP_TOPIC` and :data:`COSTMAP_TOPIC`;
    ``frame``: the world frame; ``stamp``: a message's ``Time`` as a Foxglove ``Timestamp``."""

    def __init__(self, topics: dict[str, str], frame: str, stamp: Callable[[Time], Timestamp]) -> None:
        self._map_topic = topics[MAP_TOPIC]
        self._costmap_topic = topics[COSTMAP_TOPIC]
        self._frame = frame
        self._stamp = stamp
        self._map: tuple[OccupancyGrid, bytes] | None = None
        self._next_map_ns = 0
        self._costmap_shown_ns: int | None = None
        self.plan: list[tuple[float, float]] = []
        """The running goal's plan, in the world frame; empty while there is none."""

    def map(self, message: OccupancyGrid) -> Shown:
        """A map (``drive/map``): shown at once, and again every :data:`MAP_PERIOD_NS` (:meth:`tick`)."""
        self._map = (message, shown_cells(message))
        return self._show_map(self._map, message.tm)

    def costmap(self, message: OccupancyGrid) -> Shown:
        """A costmap (``drive/costmap``): shown unless one was shown less than
        :data:`COSTMAP_PERIOD_NS` before it (one stamped earlier, a restarted clock, is shown)."""
        stamp_ns = message.tm.to_nanoseconds()
        last = self._costmap_shown_ns
        if last is not None and last <= stamp_ns < last + COSTMAP_PERIOD_NS:
            return []
        self._costmap_shown_ns = stamp_ns
        grid = grid_message(
            message, shown_cells(message), COSTMAP_FIELD, self._frame, COSTMAP_Z, self._stamp(message.tm)
        )
        return [(self._costmap_topic, grid)]

    def set_plan(self, points: list[tuple[float, float]]) -> None:
        """The running goal's plan (``drive/plan``); empty: the goal ended, no plan drawn."""
        self.plan = drawn_plan(points)

    def tick(self, tm: Time) -> Shown:
        """The ground truth's time: the map again if it is time (or the clock went back)."""
        stamp_ns = tm.to_nanoseconds()
        if self._map is None or self._next_map_ns - MAP_PERIOD_NS <= stamp_ns < self._next_map_ns:
            return []
        return self._show_map(self._map, tm)

    def _show_map(self, shown: tuple[OccupancyGrid, bytes], tm: Time) -> Shown:
        message, cells = shown
        self._next_map_ns = tm.to_nanoseconds() + MAP_PERIOD_NS
        return [(self._map_topic, grid_message(message, cells, MAP_FIELD, self._frame, MAP_Z, self._stamp(tm)))]
