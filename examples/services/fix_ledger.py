"""A fix ledger: a service that watches at a low rate (docs/extending.md).

It reads the localization's fixes (``localization/pose``: amcl's, or the stub's, once a simulated
second by default), adds up the distance between consecutive fixes, and publishes it on
``invent/<robot>/fixes/travelled`` at each fix, taking part in lockstep at 1 Hz as the odometer
(odometer.py) does at 10 Hz. The odometer takes every pose, a thousand a simulated second: beside a
composed loop running ten times faster than real time, a process of its own cannot keep up with
that, and the loop waits for it. This one crosses processes once a simulated second, so it runs
beside a composed loop at the loop's pace (``make soak-day`` runs it so, and kills it)::

    invent up --composed --with examples/services/fix_ledger.py:FixLedger --restart on-failure
"""

from __future__ import annotations

import math
from typing import Any

import msgspec

from schemas.messages import TimedPosition
from services.extension.api import Context, Lockstep, Time, UserService


class Fixes(msgspec.Struct, frozen=True):
    """``fixes/travelled``: stamped with the simulation time of the fix it answers."""

    tm: Time
    fixes: int
    """Fixes taken since the service started."""
    travelled: float
    """Metres between consecutive fixes, summed since the service started."""


class FixLedger(UserService):
    name = "fixes"
    reads = ("localization/pose",)
    lockstep = Lockstep(output="travelled", rate_hz=1.0)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        self.fixes = 0
        self.travelled = 0.0
        self.last: TimedPosition | None = None
        self.out = ctx.output("travelled", Fixes)
        ctx.subscribe(ctx.keys.localization_pose, TimedPosition, self.on_fix)

    def on_fix(self, fix: TimedPosition) -> None:
        if self.last is not None and fix.tm.to_nanoseconds() > self.last.tm.to_nanoseconds():
            self.travelled += math.hypot(fix.x - self.last.x, fix.y - self.last.y)
        self.last = fix
        self.fixes += 1
        if self.ctx.tick(fix.tm):
            self.out.put(Fixes(tm=fix.tm, fixes=self.fixes, travelled=self.travelled))

    def status(self) -> dict[str, Any]:
        return {"fixes": self.fixes, "travelled_m": round(self.travelled, 6)}
