"""What ``invent calibrate umbmark`` runs with, as typed values: ``services/cli/calibrate.py`` builds
them from its flags, ``services/launch/calibrate.py`` runs them. Pure: no zenoh."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from services.config import Config

DEFAULT_PASSES = 2


@dataclass(frozen=True)
class UmbmarkSettings:
    """Every flag of ``invent calibrate umbmark``, checked and with its default, and the robot
    description they give."""

    side: float
    """m: the square's (``--side``, else :data:`services.calibration.umbmark.DEFAULT_SIDE`)."""
    side_given: bool
    """``--side`` was given: a measured file's side must then be the same."""
    runs: int
    """Runs in each direction per benchmark (``--runs``)."""
    passes: int
    """At most this many corrections (``--passes``)."""
    sim_set: dict[str, Any]
    """``--sim-set``: the simulated body's keys (of :data:`services.config.SIM_BODY_KEYS`) and values."""
    measured: Path | None
    """``--measured``: the file of return positions measured by hand; None: in the simulator."""
    description: dict[str, Any]
    """The robot description given (``--config``, ``--set``), as written: what ``-o`` extends."""
    config: Config
    """That description, loaded."""
    report_dir: Path
    output: Path | None
    """``-o``: where the calibrated robot description goes."""
    config_file: Path | None
    robot: str | None
    sets: tuple[str, ...]
    """``--config``, ``--robot`` and ``--set`` as given: every service of a run takes them."""
    log_level: str
    """The services' log level."""
    listen: str | None
    """Where each run's session listens (None: a free port on 127.0.0.1)."""
