"""The project's own exceptions, in one place (``schemas.codec.BadInput``, a malformed or
implausible sample, stays with the wire contract it guards). Imports nothing of the project:
anything may import it."""

from __future__ import annotations

from collections.abc import Callable, Mapping


class ConfigError(ValueError):
    """An invalid configuration file, value or override (the robot description, a world, a
    scenario, a fleet, a flag); the message names the field, and the command exits with code 2."""


def refuse_given(given: Mapping[str, object], why: Callable[[str], str]) -> None:
    """ConfigError ``why(named)`` if any of ``given`` (what was asked, by name) is set: ``named``
    lists those that are, in order (``"--loop, --gui"``)."""
    named = [name for name, value in given.items() if value]
    if named:
        raise ConfigError(why(", ".join(named)))


class SessionFailed(RuntimeError):
    """A zenoh session could not be opened: the router is unreachable or refused the credentials."""


class ChildDied(RuntimeError):
    """A service the run needs ended before the run did."""


class Interrupted(RuntimeError):
    """Ctrl-C (SIGINT or SIGTERM) while the run lasted."""


class ConsumerStalled(RuntimeError):
    """A service taking every sample of a replayed key took none for too long: the replay gives up."""


class RunFailed(RuntimeError):
    """A calibration run did not drive its square to the end (the drive gave it up), or the runs'
    return positions are beyond what the formulas take."""
