"""A patrol: a service that commands (docs/extending.md).

It sends the drive its goals in turn (``drive/goal/send``, docs/protocol.md section 7.3): the
corners of a 1 m square, then round again, each sent once the drive's ``drive/outcome`` says
the one before has ended (completed or not). It publishes its progress on
``invent/<robot>/patrol/progress`` and says it in its status. It needs a drive in goal mode::

    invent up --goals --with examples/services/patrol.py:Patrol

(``--goals`` runs until Ctrl-C). With ``--secure`` it may query ``drive/goal/send`` only, as its
``calls`` declares. Alone, beside a running ``invent up --goals``::

    invent service examples/services/patrol.py:Patrol --connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

from typing import Any

import msgspec

from schemas.messages import ScenarioOutcome
from schemas.navigation import GoalReply, GoalRequest
from services.extension.api import Context, Reply, Time, UserService

CORNERS = ((1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0))
RETRY_S = 0.5
"""How often (wall time) it tries again while no goal of it runs: the drive not there yet, a goal refused."""


class Progress(msgspec.Struct, frozen=True):
    """``patrol/progress``: a goal sent, or one ended."""

    tm: Time
    """The simulation time it happened at (of the outcome, or the newest clock seen)."""
    goal: str
    """The drive's id of the goal."""
    corner: int
    event: str
    """``sent``, or how the goal ended (``completed``, ``aborted``, ``timed_out``, ``canceled``)."""
    laps: int


class Patrol(UserService):
    name = "patrol"
    reads = ("drive/outcome",)
    calls = ("drive/goal/send",)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        self.corner = 0
        self.laps = 0
        self.running: str | None = None
        """The drive's id of the goal on its way; None while none is."""
        self.asking = False
        self.completed = 0
        self.ended: dict[str, int] = {}
        self.refusals = 0
        self.progress = ctx.output("progress", Progress)
        ctx.subscribe(ctx.keys.drive_outcome, ScenarioOutcome, self.on_outcome)
        ctx.timer(RETRY_S, self.send_next)

    def send_next(self) -> None:
        if self.running is not None or self.asking:
            return
        x, y = CORNERS[self.corner]
        self.asking = True
        self.ctx.call("drive/goal/send", GoalRequest(x=x, y=y), GoalReply, self.on_reply)

    def on_reply(self, reply: Reply[GoalReply]) -> None:
        self.asking = False
        if reply.value is None or not reply.value.accepted:
            self.refusals += 1
            why = reply.error if reply.value is None else reply.value.reason
            self.ctx.log.info("goal to corner %d not sent (%s): trying again", self.corner, why)
            return
        self.running = reply.value.id
        self._say(self.ctx.sim_time or Time(sec=0, nsec=0), "sent")

    def on_outcome(self, outcome: ScenarioOutcome) -> None:
        if self.running is None or outcome.goal_id != self.running:
            return
        self.ended[outcome.outcome] = self.ended.get(outcome.outcome, 0) + 1
        self.completed += outcome.outcome == "completed"
        self._say(outcome.tm, outcome.outcome)
        self.running = None
        self.corner = (self.corner + 1) % len(CORNERS)
        if self.corner == 0:
            self.laps += 1
        self.send_next()

    def _say(self, tm: Time, event: str) -> None:
        goal = self.running or ""
        self.progress.put(Progress(tm=tm, goal=goal, corner=self.corner, event=event, laps=self.laps))
        self.ctx.log.info("corner %d %s: goal %s", self.corner, event, goal)

    def status(self) -> dict[str, Any]:
        return {
            "corner": self.corner,
            "laps": self.laps,
            "running": self.running,
            "completed": self.completed,
            "ended": dict(self.ended),
            "refusals": self.refusals,
        }
