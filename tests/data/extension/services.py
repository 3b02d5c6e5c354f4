"""User services for tests/test_extension*.py: written against services/extension/api.py only."""

from __future__ import annotations

from typing import Any

import msgspec

from schemas.navigation import GoalReply, GoalRequest
from services.extension.api import BadInput, Context, Delivery, Lockstep, Reply, Time, UserService


class Number(msgspec.Struct, frozen=True):
    tm: Time
    value: float


class Ask(msgspec.Struct, frozen=True):
    value: float = 0.0


class Doubler(UserService):
    """Doubles every ``doubler/input`` it takes onto ``doubler/output``; a negative one is bad input;
    ``doubler/scale`` (acts) sets the factor; ``doubler/echo`` (reads) answers the factor; it
    calls ``drive/goal/send`` when ``doubler/ask`` asks it; ``doubler/stop`` ends it with code 7."""

    name = "doubler"
    calls = ("drive/goal/send",)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        self.factor = 2.0
        self.ticks = 0
        self.replies: list[str] = []
        self.out = ctx.output("output", Number)
        ctx.subscribe(ctx.keys.own(self.name, "input"), Number, self.on_input)
        ctx.subscribe(ctx.keys.own(self.name, "newest"), Number, self.on_input, Delivery.NEWEST)
        ctx.queryable("scale", self.on_scale, Ask, acts=True)
        ctx.queryable("echo", lambda _ask: {"factor": self.factor}, Ask)
        ctx.queryable("ask", self.on_ask, Ask, acts=True)
        ctx.queryable("stop", lambda _ask: ctx.finish(7) or {"stopping": True}, Ask, acts=True)
        ctx.timer(0.05, self.on_timer)

    def on_input(self, number: Number) -> None:
        if number.value < 0:
            raise BadInput(f"negative: {number.value}")
        self.out.put(Number(tm=number.tm, value=number.value * self.factor))

    def on_scale(self, ask: Ask) -> dict[str, float]:
        self.factor = ask.value
        return {"factor": self.factor}

    def on_ask(self, ask: Ask) -> dict[str, bool]:
        self.ctx.call("drive/goal/send", GoalRequest(x=ask.value, y=0.0), GoalReply, self.on_reply, timeout_s=1.0)
        return {"asked": True}

    def on_reply(self, reply: Reply[GoalReply]) -> None:
        self.replies.append(reply.value.id if reply.value is not None else f"error: {reply.error}")

    def on_timer(self) -> None:
        self.ticks += 1

    def status(self) -> dict[str, Any]:
        return {"factor": self.factor, "timer_ticks": self.ticks, "replies": self.replies}


class Intruder(UserService):
    """Tries, every 50 ms, to put on other services' keys (motor/torque, drive/target_velocity) and
    to query a queryable it does not declare (drive/goal/send), bypassing the API with the raw
    session; and puts on its own key through the API. For the --secure tests: the router must
    refuse the first three and let the last through."""

    name = "intruder"

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        self.attempts = 0
        self.goal_replies = 0
        self.own = ctx.output("attempts", Number)
        self._session = ctx._node.session
        ctx.timer(0.05, self.attempt)

    def attempt(self) -> None:
        self.attempts += 1
        keys = self.ctx.keys
        marker = b'{"intruder": %d}' % self.attempts
        self._session.put(keys.motor_torque, marker)
        self._session.put(keys.drive_target_velocity, marker)
        self._session.get(keys.drive_goal_send, self._on_goal_reply, payload=b'{"x": 9.0, "y": 9.0}', timeout=0.5)
        self.own.put(Number(tm=self.ctx.sim_time or Time(sec=0, nsec=0), value=float(self.attempts)))

    def _on_goal_reply(self, reply: Any) -> None:  # zenoh's thread: counts only
        if reply.ok is not None:
            self.goal_replies += 1

    def status(self) -> dict[str, Any]:
        return {"attempts": self.attempts, "goal_replies": self.goal_replies}


class NotAService:
    name = "plain"


class Named(UserService):
    name = "motor"


class Upper(UserService):
    name = "Loud"


class Reserved(UserService):
    name = "operator"


class Nameless(UserService):
    pass


class BadRate(UserService):
    name = "badrate"
    lockstep = Lockstep(output="out", rate_hz=-1.0)


class Wildcard(UserService):
    name = "wildcard"
    calls = ("drive/**",)


class ReadsWildcard(UserService):
    name = "reads_wildcard"
    reads = ("sim/**",)


class ReadsUndeclared(UserService):
    """Subscribes the odometry's pose without declaring it in ``reads``: refused when it starts."""

    name = "reads_undeclared"

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        ctx.subscribe(ctx.keys.odometry_pose, Number, lambda _number: None)


class UndeclaredOutput(UserService):
    """Takes part in lockstep on an output it never declares: refused when it starts."""

    name = "undeclared"
    lockstep = Lockstep(output="nowhere", rate_hz=10.0)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)


class Unstamped(msgspec.Struct, frozen=True):
    value: float


class UnstampedOutput(UserService):
    name = "unstamped"
    lockstep = Lockstep(output="out", rate_hz=10.0)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        ctx.output("out", Unstamped)
