"""The exit statuses of every ``invent`` command, in one place (docs/protocol.md section 8.5 lists
those of ``invent up`` and ``invent drive``). Imports nothing of the project: anything may import it."""

from __future__ import annotations

import enum


class ExitStatus(enum.IntEnum):
    OK = 0
    """Done: the command did what it was asked (a drive's scenario ``completed``)."""
    FAILURE = 1
    """It could not: no zenoh session, nothing answered a call, a service of the run died, a replay's
    consumer stalled, a view could not listen, a ``--strict`` run degraded, a calibration run did not complete."""
    CONFIG = 2
    """Bad arguments or configuration, refused before anything ran (a usage error of the command line too)."""
    ABORTED = 3
    """A drive's scenario given up: the motor stayed latched stopped (services/drive/outcome.py)."""
    TIMED_OUT = 4
    """A drive's scenario given up: a pass outlasted its time limit (services/drive/outcome.py)."""
    CANCELED = 5
    """A goal canceled before it ended (``invent goto``: a cancel, Ctrl-C, or a newer goal preempting it)."""
    INTERRUPTED = 130
    """Ctrl-C (SIGINT) or SIGTERM ended a run of ``invent up`` or ``invent calibrate`` before it ended by itself,
    or ``invent goto`` before its goal was sent (128 + SIGINT)."""
