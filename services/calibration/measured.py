"""Return positions measured by hand on a real robot (``invent calibrate umbmark --measured FILE``),
read from a small TOML or CSV file (pure). docs/odometry.md, "Measuring by hand", shows both.

Each run's end is where the axle centre stopped, in metres, in the frame of the start: x along
the first leg, y to the robot's left at the start. ``odometry_x``/``odometry_y`` (default 0) are
where the robot's own odometry said it stopped, when it did not stop exactly on the start.

TOML::

    side = 4.0                                  # m, optional (else --side)
    cw = [{ x = -0.102, y = -0.098 }, { x = -0.097, y = -0.104 }]
    ccw = [{ x = 0.031, y = -0.027, odometry_x = 0.002 }]

CSV (the side from ``--side``)::

    direction,x,y,odometry_x,odometry_y
    cw,-0.102,-0.098,0,0
    ccw,0.031,-0.027,0.002,0

The last two columns may be left out; blank lines and lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import msgspec

from services.calibration.umbmark import Direction, Point, return_error
from services.config import ConfigError, convert_toml, require_finite_fields

CSV_COLUMNS = ("direction", "x", "y", "odometry_x", "odometry_y")


class MeasuredEnd(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    x: float
    """m: where the axle centre stopped, along the first leg."""
    y: float
    """m: where it stopped, to the left of the first leg."""
    odometry_x: float = 0.0
    """m: where the odometry said it stopped (x)."""
    odometry_y: float = 0.0

    def __post_init__(self) -> None:
        require_finite_fields(self)

    @property
    def error(self) -> Point:
        return return_error((self.x, self.y), (self.odometry_x, self.odometry_y))


Runs = Annotated[list[MeasuredEnd], msgspec.Meta(min_length=1)]


class MeasuredFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    side: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    cw: Runs
    ccw: Runs

    def __post_init__(self) -> None:
        if self.side is not None and not math.isfinite(self.side):
            raise ValueError("`side` must be finite")


@dataclass(frozen=True)
class Measured:
    """The return position errors of a file, and its square's side (None: not in the file)."""

    side: float | None
    errors: dict[Direction, list[Point]]


def read_measured(path: Path) -> Measured:
    """The runs of a ``.toml`` or ``.csv`` file; ConfigError naming the file and what is wrong."""
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"--measured {path}: {error.strerror}") from None
    if path.suffix.lower() == ".toml":
        return parse_measured_toml(text, f"--measured {path}")
    if path.suffix.lower() == ".csv":
        return parse_measured_csv(text, f"--measured {path}")
    raise ConfigError(f"--measured {path}: a .toml or .csv file (docs/odometry.md, Measuring by hand)")


def parse_measured_toml(text: str, what: str) -> Measured:
    measured = convert_toml(text, MeasuredFile, what)
    return Measured(
        measured.side,
        {Direction.CW: [end.error for end in measured.cw], Direction.CCW: [end.error for end in measured.ccw]},
    )


def parse_measured_csv(text: str, what: str) -> Measured:
    lines = [(number, line) for number, line in enumerate(text.splitlines(), 1) if line.strip()]
    lines = [(number, line) for number, line in lines if not line.lstrip().startswith("#")]
    if not lines:
        raise ConfigError(f"{what}: empty (the first line names the columns: {','.join(CSV_COLUMNS)})")
    rows = list(csv.reader(line for _, line in lines))
    header = [name.strip() for name in rows[0]]
    if header not in (list(CSV_COLUMNS[:3]), list(CSV_COLUMNS)):
        raise ConfigError(
            f"{what}: line {lines[0][0]}: the columns must be {','.join(CSV_COLUMNS[:3])} or "
            f"{','.join(CSV_COLUMNS)}, got {','.join(header)}"
        )
    errors: dict[Direction, list[Point]] = {Direction.CW: [], Direction.CCW: []}
    for (number, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) != len(header):
            raise ConfigError(f"{what}: line {number}: {len(row)} values, expected {len(header)}")
        name = row[0].strip().lower()
        if name not in {str(direction) for direction in Direction}:
            raise ConfigError(f"{what}: line {number}: direction {row[0].strip()!r} must be cw or ccw")
        try:
            values = [float(value) for value in row[1:]]
        except ValueError:
            raise ConfigError(f"{what}: line {number}: {','.join(row[1:])} must be numbers (metres)") from None
        if not all(math.isfinite(value) for value in values):
            raise ConfigError(f"{what}: line {number}: the values must be finite")
        truth, odometry = (values[0], values[1]), (values[2], values[3]) if len(values) == 4 else (0.0, 0.0)
        errors[Direction(name)].append(return_error(truth, odometry))
    for direction, points in errors.items():
        if not points:
            raise ConfigError(f"{what}: no {direction} runs: UMBmark needs runs in both directions")
    return Measured(None, errors)
