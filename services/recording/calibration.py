"""What ``invent calibrate umbmark`` leaves to look at (no zenoh here):

- the paper's figure (``umbmark.png``): each benchmark's return position errors, clockwise and
  counter-clockwise, with their centres of gravity, in millimetres in the frame of the start;
- the runs' paths for Foxglove (``umbmark.mcap``): ``/umbmark/paths`` (``foxglove.SceneUpdate``,
  frame ``world``) holds the square and, per run, the ground truth and the odometry's path and the
  point where the robot really stopped, one message per run, a second apart on the timeline;
  ``/umbmark/runs`` (JSON) each run's end points and error.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from foxglove.messages import Color, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp, Vector3

from schemas.messages import NANOSECONDS_PER_SECOND
from services.calibration.benchmark import RunPaths
from services.calibration.umbmark import Direction, Umbmark, square
from services.recording.mcap_files import McapWriter
from services.recording.scene import WORLD_FRAME
from services.recording.scene_shapes import foxglove_pose, ground_line

PATHS_TOPIC = "/umbmark/paths"
RUNS_TOPIC = "/umbmark/runs"
RUNS_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "invent.UmbmarkRun",
    "description": "One UMBmark run: where the robot stopped (ground truth), where its odometry said it stopped, "
    "and the return position error (truth minus odometry), m",
    "properties": {
        "benchmark": {"type": "string"},
        "run": {"type": "string"},
        "truth_end": {"type": "array", "items": {"type": "number"}},
        "odometry_end": {"type": "array", "items": {"type": "number"}},
        "error": {"type": "array", "items": {"type": "number"}},
    },
}
_COLOURS = ("#d62728", "#2ca02c", "#1f77b4", "#9467bd")
"""One per benchmark: before, after pass 1, after pass 2, ..."""
_SQUARE = Color(r=0.5, g=0.5, b=0.5, a=1.0)
_ODOMETRY = Color(r=0.2, g=0.2, b=0.2, a=0.6)
_MARKERS = {Direction.CW: "o", Direction.CCW: "s"}


def _colour(index: int) -> str:
    return _COLOURS[index % len(_COLOURS)]


def _foxglove_colour(hex_colour: str, alpha: float = 1.0) -> Color:
    red, green, blue = (int(hex_colour[i : i + 2], 16) / 255.0 for i in (1, 3, 5))
    return Color(r=red, g=green, b=blue, a=alpha)


def write_figure(path: Path, side: float, benchmarks: Sequence[tuple[str, Umbmark]]) -> Path:
    """The paper's figure: each benchmark's return position errors (cw: circles, ccw: squares) and
    their centres of gravity (large, labelled), in mm."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7.5, 7.0))
    for index, (label, result) in enumerate(benchmarks):
        colour = _colour(index)
        for direction, points, cg in (
            (Direction.CW, result.cw, result.cg_cw),
            (Direction.CCW, result.ccw, result.cg_ccw),
        ):
            marker = _MARKERS[direction]
            axes.scatter(
                [x * 1000 for x, _ in points],
                [y * 1000 for _, y in points],
                marker=marker,
                facecolors="none",
                edgecolors=colour,
                s=40,
                label=f"{label}, {direction} runs",
            )
            axes.scatter([cg[0] * 1000], [cg[1] * 1000], marker=marker, color=colour, s=140, zorder=3)
            axes.annotate(
                f"cg {direction}",
                (cg[0] * 1000, cg[1] * 1000),
                textcoords="offset points",
                xytext=(8, 6),
                color=colour,
            )
    axes.axhline(0.0, color="grey", linewidth=0.5)
    axes.axvline(0.0, color="grey", linewidth=0.5)
    axes.set_xlabel("x error [mm] (along the first leg)")
    axes.set_ylabel("y error [mm] (to the left of the first leg)")
    axes.set_aspect("equal", adjustable="datalim")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize="small")
    lines = [
        f"{label}: E_max,syst {result.e_max_syst * 1000:.1f} mm (Ed {result.ed:.5f}, Eb {result.eb:.5f})"
        for label, result in benchmarks
    ]
    axes.set_title(f"UMBmark, {side:g} m square: return position errors\n" + "\n".join(lines), fontsize="small")
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


def write_paths_recording(path: Path, side: float, benchmarks: Sequence[tuple[str, Sequence[RunPaths]]]) -> Path:
    """``umbmark.mcap``: the squares, then each run's paths, one message per run."""
    writer = McapWriter(path)
    try:
        squares = [
            SceneEntity(
                timestamp=Timestamp(0, 0),
                frame_id=WORLD_FRAME,
                id=f"square/{direction}",
                lines=[ground_line([(0.0, 0.0), *square(side, direction)], _SQUARE, 0.01)],
            )
            for direction in Direction
        ]
        writer.write_foxglove(PATHS_TOPIC, SceneUpdate(entities=squares), 0, 0)
        runs = [(index, label, run) for index, (label, paths) in enumerate(benchmarks) for run in paths]
        for number, (index, label, run) in enumerate(runs, 1):
            stamp_ns = number * NANOSECONDS_PER_SECOND
            timestamp = Timestamp(number, 0)
            colour = _foxglove_colour(_colour(index))
            (x, y), (odometry_x, odometry_y) = run.truth_end, run.odometry_end
            entity = SceneEntity(
                timestamp=timestamp,
                frame_id=WORLD_FRAME,
                id=f"{label}/{run.name}",
                lines=[ground_line(run.truth, colour, 0.02), ground_line(run.odometry, _ODOMETRY, 0.01)],
                spheres=[
                    SpherePrimitive(
                        pose=foxglove_pose(x, y, 0.02),
                        size=Vector3(x=0.05, y=0.05, z=0.05),
                        color=colour,
                    )
                ],
            )
            writer.write_foxglove(PATHS_TOPIC, SceneUpdate(entities=[entity]), stamp_ns, stamp_ns)
            writer.write_json(
                RUNS_TOPIC,
                {
                    "benchmark": label,
                    "run": run.name,
                    "truth_end": [x, y],
                    "odometry_end": [odometry_x, odometry_y],
                    "error": [x - odometry_x, y - odometry_y],
                },
                RUNS_SCHEMA,
                stamp_ns,
                stamp_ns,
            )
    finally:
        writer.close()
    return path
