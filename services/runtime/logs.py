"""Logging: the format, and the one rate-limited log every "this can happen at will" line goes
through (bad input, internal errors, late torques), with the bad-input count a status reports.

Bad input (docs/protocol.md section 8) never kills a service: it is dropped, logged in one line
naming the key and the reason (at most one line per key per :data:`LOG_INTERVAL_S`), and counted.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

from schemas.status import BadInputCount, BadInputStatus

LOG_INTERVAL_S = 1.0
"""At most one line per kind (bad input per key, internal errors per key, ...) per interval."""

log = logging.getLogger("invent")


class RateLimitedLog:
    """One log line per key per interval at most; the lines left out are counted and said with
    the next. For anything a sender can make happen at will: bad input, internal errors, late
    torques (at 1 kHz, a line per occurrence would fill the log)."""

    def __init__(self, logger: logging.Logger, interval_s: float = LOG_INTERVAL_S) -> None:
        self._logger = logger
        self._interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def __call__(self, key: str, level: int, message: str, *args: Any, exc_info: bool = False) -> None:
        now = time.monotonic()
        if now - self._last.get(key, -math.inf) < self._interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        suppressed = self._suppressed.pop(key, 0)
        more = f" ({suppressed} more since the last line)" if suppressed else ""
        self._logger.log(level, message + more, *args, exc_info=exc_info)
        self._last[key] = now


@dataclass
class _KeyErrors:
    count: int = 0
    last_reason: str = ""


@dataclass
class BadInputCounter:
    """Counts bad input per key and logs at most one line per key per interval."""

    service: str
    by_key: dict[str, _KeyErrors] = field(default_factory=dict)
    _log: RateLimitedLog = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._log = RateLimitedLog(log.getChild(self.service))

    def record(self, key: str, reason: str) -> None:
        entry = self.by_key.setdefault(key, _KeyErrors())
        entry.count += 1
        entry.last_reason = reason
        self._log(key, logging.WARNING, "bad input on %s: %s; dropped", key, reason)

    @property
    def total(self) -> int:
        return sum(entry.count for entry in self.by_key.values())

    def reset(self) -> None:
        self.by_key.clear()

    def status(self) -> BadInputStatus:
        return BadInputStatus(
            self.total, {key: BadInputCount(e.count, e.last_reason) for key, e in self.by_key.items()}
        )


LOG_LEVELS = ("debug", "info", "warning", "error")
"""``--log-level``'s choices: the services' and the calibration's."""


def configure_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s.%(msecs)03d %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
