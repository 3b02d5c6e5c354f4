"""The exit statuses of ``invent`` and every service it runs: one name for each number."""

from __future__ import annotations

import enum


class ExitStatus(enum.IntEnum):
    OK = 0
    """Done: the command did what it was asked."""
    FAILURE = 1
    """A run failed: a service died or a run did not complete."""
    CONFIG = 2
    """Bad arguments or configuration, refused before anything ran."""
    ABORTED = 3
    """The drive gave its scenario up before the end (its outcome ``aborted``)."""
    TIMED_OUT = 4
    """The drive's scenario ran past its time limit (its outcome ``timed_out``)."""
    INTERRUPTED = 130
    """Interrupted (Ctrl-C): 128 + SIGINT's number, as a shell reports it."""
