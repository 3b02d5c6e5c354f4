"""The project's exceptions."""

from __future__ import annotations


class RunFailed(RuntimeError):
    """A run did not drive its square to the end (the drive gave it up), or the runs' return
    positions are beyond what the formulas take."""
