"""Whether a PyBullet window can be opened: checked by the sim and, before it starts anything, by
``invent up --gui`` (no pybullet import here: every ``invent`` command loads this)."""

from __future__ import annotations

import os

from services.config import ConfigError

DISPLAY_VARIABLE = "DISPLAY"


def require_display() -> None:
    """ConfigError unless a window can be opened."""
    if not os.environ.get(DISPLAY_VARIABLE):
        raise ConfigError(f"--gui needs a display, but ${DISPLAY_VARIABLE} is not set (run without --gui)")
