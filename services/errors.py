"""The project's exceptions, in one place.

``schemas.codec.BadInput`` (a malformed or implausible sample) stays with the wire contract it
guards. This module imports nothing of the project, so that every layer may import it.
"""

from __future__ import annotations


class ConfigError(ValueError):
    """An invalid configuration file, value or override (the robot description, a world, a
    scenario, a fleet, a flag); the message names the field, and the command exits with code 2."""


class RunFailed(RuntimeError):
    """A run did not drive its square to the end (the drive gave it up), or the runs' return
    positions are beyond what the formulas take."""
