"""The project's own exceptions, where a reader looks for them (``schemas.codec.BadInput`` stays
with the codec). Imports nothing of the project: anything may import it."""

from __future__ import annotations


class SessionFailed(RuntimeError):
    """A zenoh session could not be opened: the router is unreachable or refused the credentials."""


class ChildDied(RuntimeError):
    """A service the run needs ended before the run did."""


class Interrupted(RuntimeError):
    """Ctrl-C (SIGINT or SIGTERM) while the run lasted."""


class ConsumerStalled(RuntimeError):
    """A service taking every sample of a replayed key took none for too long: the replay gives up."""
