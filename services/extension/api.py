"""The public API for writing a service of one's own (docs/extending.md): a thin, typed facade over
:class:`~services.runtime.node.Node`, stable across releases of the stack.

A user service is a subclass of :class:`UserService` in a Python file. Its class attributes say
what the launcher needs to know before it starts (its ``name``, the queryables it ``calls``, its
``lockstep`` participation, or that it ``drives`` the robot); its ``__init__(ctx)`` declares its inputs, outputs, queryables and
timers on the :class:`Context`; everything it declares is handled on the service's one thread.
``invent service FILE.py:NAME`` runs one alone; ``invent up --with FILE.py:NAME`` beside the loop.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Generic, TypeVar

import msgspec
import zenoh

from schemas.codec import BadInput, decode, encode
from schemas.drive_status import DriveStatus
from schemas.keys import Keys, Service, UserServiceName, service_name, user_service_name, validate_own_key
from schemas.messages import NANOSECONDS_PER_SECOND, Time, TimedDoubleSeq
from schemas.status import UserLockstep, UserServiceStatus
from services.clock.sim_time import PeriodicSchedule
from services.config import Config
from services.extension.drive_output import DriveOutput
from services.runtime.inputs import Delivery as _RuntimeDelivery
from services.runtime.node import Node, Wait

__all__ = [
    "BadInput",
    "Context",
    "Delivery",
    "Drives",
    "Keys",
    "Lockstep",
    "Output",
    "Reply",
    "Time",
    "UserService",
]

MessageT = TypeVar("MessageT", bound=msgspec.Struct)
CALL_TIMEOUT_S = 2.0
"""How long :meth:`Context.call` waits for a reply by default."""


class Delivery(StrEnum):
    """Which samples of an input a handler gets."""

    EVERY = "every"
    """Every sample, in arrival order, each once (bounded: a flood beyond the service's event queue
    is dropped and counted in ``dropped_events``): for what must not be missed (poses to integrate)."""
    NEWEST = "newest"
    """Only the newest sample, looked at whenever the thread is free: for a value whose latest is
    all that counts (a state, a scan), so a flood never delays the service."""


_DELIVERIES = {Delivery.EVERY: _RuntimeDelivery.QUEUED, Delivery.NEWEST: _RuntimeDelivery.SAMPLED}


@dataclass(frozen=True)
class Lockstep:
    """Taking part in lockstep (docs/extending.md, Lockstep): at every tick of ``rate_hz`` per second
    of simulation time, the simulator waits for one message on ``output`` (a key under the service's
    own name, declared with :meth:`Context.output`) stamped with the tick's stamp (``tm``)."""

    output: str
    rate_hz: float


@dataclass(frozen=True)
class Drives:
    """Being the robot's velocity source in place of the built-in drive (docs/extending.md, A
    service that drives): its commands (:meth:`Context.drive`) at ``rate_hz`` ticks per second of
    simulation time, on the drive's keys, with the drive's lockstep part, limits, give-up rule and
    outcome; ``invent up --with`` then starts no built-in drive."""

    rate_hz: float


@dataclass(frozen=True)
class Reply(Generic[MessageT]):
    """What a :meth:`Context.call` got: the decoded reply, or ``error`` (the queryable's error, no
    reply within the timeout, a reply that does not decode)."""

    value: MessageT | None
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.value is not None


class Output(Generic[MessageT]):
    """A publisher of ``message_type`` on a key under the service's own name."""

    def __init__(self, node: Node, key: str, message_type: type[MessageT]) -> None:
        self.key = key
        self.message_type = message_type
        self._publisher = node.publisher(key)
        self.published = 0

    def put(self, message: MessageT) -> None:
        """Publish ``message`` (encoded as JSON). TypeError for a message of another type."""
        if not isinstance(message, self.message_type):
            raise TypeError(f"{self.key} carries {self.message_type.__name__}, not {type(message).__name__}")
        self._publisher.put(message)
        self.published += 1

    @property
    def matched(self) -> bool:
        """Whether someone subscribes to it now."""
        return self._publisher.matched


class UserService:
    """Subclass this. Declare in ``__init__`` (which must call ``super().__init__(ctx)``); handle
    on the service thread; never block in a handler (a slow handler delays every other one)."""

    name: ClassVar[str]
    """Its name: one key chunk, lower case (``[a-z][a-z0-9_]*``), not a built-in's (``motor``, ...):
    its keys are ``invent/<robot>/<name>/...``."""
    reads: ClassVar[tuple[str, ...]] = ()
    """The keys of other services it subscribes, relative to the robot (``"odometry/pose"``):
    :meth:`Context.subscribe` refuses any other (its own keys it may always read), and a ``--secure``
    run lets it subscribe only these (and ``sim/clock``, which its runtime reads)."""
    calls: ClassVar[tuple[str, ...]] = ()
    """The queryables of other services it calls, relative to the robot (``"drive/goal/send"``):
    :meth:`Context.call` refuses any other, and a ``--secure`` run lets it query only these."""
    lockstep: ClassVar[Lockstep | None] = None
    """Its lockstep participation, or None (it is never waited for)."""
    drives: ClassVar[Drives | None] = None
    """``Drives(rate_hz)``: it commands the robot's velocity in place of the built-in drive
    (:meth:`Context.drive`), as the drive, with exactly the drive's rights; None: it does not."""

    def __init__(self, ctx: Context) -> None:
        self.ctx = ctx

    def status(self) -> dict[str, Any]:
        """Merged into its ``<name>/status`` reply (with the runtime's own fields); JSON-encodable."""
        return {}

    def close(self) -> None:
        """Release what it holds beyond what it declared (files); called once, on the service thread."""


class Context:
    """What a user service is given: its keys, the robot description, inputs, outputs, queryables,
    calls, timers, the simulation clock, status and its end. Every method is called on the service
    thread (in ``__init__`` or a handler); every handler runs there too."""

    def __init__(
        self, node: Node, config: Config, service: type[UserService], on_finish: Callable[[int], None]
    ) -> None:
        self._node = node
        self._on_finish = on_finish
        self._service_type = service
        self.name: UserServiceName = user_service_name(service.name)
        self.keys: Keys = node.keys
        """The robot's keys: ``ctx.keys.odometry_pose``, ``ctx.keys.drive_goal_send``, ..."""
        self.robot = node.keys.robot
        self.config = config
        """The robot description (``--config``, ``--set``): ``ctx.config.robot.wheel_radius``, ..."""
        self.log: logging.Logger = node.log
        """Its logger: ``invent up`` prefixes each line with the service's name."""
        self._outputs: dict[str, Output[Any]] = {}
        self._timers: list[_Timer] = []
        self._sim_ns: int | None = None
        self._sim_alive = False
        self._schedule: PeriodicSchedule | None = None
        self._calls = {"sent": 0, "replied": 0, "failed": 0}
        self._driving: DriveOutput | None = None
        node.watch(Service.SIM, self._on_sim)
        node.subscribe(node.keys.sim_clock, TimedDoubleSeq, self._on_clock, _RuntimeDelivery.SAMPLED)
        node.wait_with(self._next_wait)

    # --- inputs ---

    def subscribe(
        self,
        key: str,
        message_type: type[MessageT],
        handler: Callable[[MessageT], None],
        delivery: Delivery = Delivery.EVERY,
    ) -> None:
        """Call ``handler(message)`` for the samples of ``key`` (one of its own, or one the class's
        ``reads`` lists: ``ctx.keys.odometry_pose``; ValueError otherwise) that decode as
        ``message_type``. A sample that does not decode, and a handler that raises :class:`BadInput`
        (or anything else), is counted in ``bad_input`` (``internal_errors``) and logged at most once
        a second: the service lives on."""
        relative = key.removeprefix(f"{self.keys.prefix}/")
        own = relative.startswith(f"{self.name}/")
        if relative == key or not (own or relative in self._service_type.reads):
            raise ValueError(f"{key!r} is not in {self._service_type.__name__}.reads {self._service_type.reads}")
        self._node.subscribe(key, message_type, handler, _DELIVERIES[Delivery(delivery)])

    def watch(self, service: str, on_change: Callable[[bool], None]) -> None:
        """``on_change(alive)`` whenever ``service`` (``"drive"``, another user service) comes or goes."""
        self._node.watch(service_name(service), on_change)

    # --- outputs and queryables ---

    def output(self, key: str, message_type: type[MessageT]) -> Output[MessageT]:
        """A publisher on ``invent/<robot>/<name>/<key>`` (``key``: ``"distance"``, ``"progress/leg"``).
        ValueError for a service that drives: it has the drive's keys only."""
        self._refuse_if_driving("an output")
        if key in self._outputs:
            raise ValueError(f"output {key!r} declared twice")
        output = Output(self._node, self.keys.own(self.name, key), message_type)
        self._outputs[validate_own_key(key)] = output
        return output

    def queryable(
        self,
        key: str,
        handler: Callable[[MessageT], Any],
        request_type: type[MessageT],
        *,
        acts: bool = False,
    ) -> None:
        """Answer queries on ``invent/<robot>/<name>/<key>``: ``handler(request)`` (the payload
        decoded as ``request_type``) returns the reply (a msgspec Struct or anything JSON-encodable;
        None: no reply), or raises :class:`BadInput` (an error reply naming the reason). ``acts``: it
        changes something, so it answers only a query on exactly its key, never a wildcard's.
        ValueError for a service that drives: it has the drive's keys only."""
        self._refuse_if_driving("a queryable")

        def answer(payload: bytes) -> Any:
            return handler(decode(request_type, payload or b"{}"))

        self._node.queryable(self.keys.own(self.name, key), answer, mutates=acts)

    def call(
        self,
        key: str,
        request: msgspec.Struct,
        reply_type: type[MessageT],
        on_reply: Callable[[Reply[MessageT]], None],
        timeout_s: float = CALL_TIMEOUT_S,
    ) -> None:
        """Query another service's queryable ``key`` (relative to the robot, listed in the class's
        ``calls``: ValueError otherwise) with ``request``; ``on_reply(reply)`` runs later, on the
        service thread, once (the first reply, or the error). Never waits."""
        if key not in self._service_type.calls:
            raise ValueError(f"{key!r} is not in {self._service_type.__name__}.calls {self._service_type.calls}")
        self._calls["sent"] += 1
        done = False

        def settle(reply: Reply[MessageT]) -> None:
            nonlocal done
            if done:
                return
            done = True
            self._calls["replied" if reply.ok else "failed"] += 1
            on_reply(reply)

        def take(result: tuple[bytes | None, str]) -> None:
            payload, error = result
            if payload is None:
                settle(Reply(None, error))
                return
            try:
                settle(Reply(decode(reply_type, payload)))
            except BadInput as bad:
                settle(Reply(None, f"reply: {bad}"))

        post = self._node.executor.post

        def on_zenoh_reply(reply: zenoh.Reply) -> None:  # zenoh's thread: hand over, nothing else
            if reply.ok is not None:
                post(take, (reply.ok.payload.to_bytes(), ""))
            else:
                error = reply.err
                post(take, (None, "error reply" if error is None else _error_text(error.payload.to_bytes())))

        def on_done() -> None:
            post(take, (None, f"no reply from {key} (nothing serves it yet, or none within {timeout_s:g} s)"))

        self._node.session.get(
            f"{self.keys.prefix}/{key}",
            zenoh.handlers.Callback(on_zenoh_reply, on_done),
            payload=encode(request),
            timeout=timeout_s,
        )

    # --- time ---

    def timer(self, period_s: float, callback: Callable[[], None]) -> None:
        """Call ``callback()`` every ``period_s`` seconds of wall time (first after one period)."""
        if not period_s > 0.0:
            raise ValueError(f"timer period must be > 0, got {period_s}")
        self._timers.append(_Timer(time.monotonic() + period_s, period_s, callback))

    @property
    def sim_time(self) -> Time | None:
        """The simulation time of the newest ``sim/clock`` seen (None before any): at the simulator's
        observed steps, so it may be behind by a few steps; a lockstep output is stamped with the
        stamp of the input that made it (:meth:`tick`), never with this."""
        return None if self._sim_ns is None else Time.from_nanoseconds(self._sim_ns)

    @property
    def sim_alive(self) -> bool:
        return self._sim_alive

    def tick(self, stamp: Time) -> bool:
        """For a lockstep participant: whether ``stamp`` (an input's, in simulation time) takes its
        next tick, the grid ``round(k·1e9/rate_hz)`` ns that the simulator waits on; publish the
        ``lockstep.output`` stamped ``stamp`` when it does. Call it with every input's stamp, in order."""
        if self._schedule is None:
            raise ValueError(f"{self._service_type.__name__} has no lockstep (its class attribute)")
        return self._schedule.due(stamp.to_nanoseconds())

    # --- driving ---

    def drive(self, stamp: Time, vx: float, w: float) -> bool:
        """For a service that ``drives``: command the robot at ``stamp`` (the stamp of the input the
        command comes from, in simulation time; call it with every such input's stamp, in order).
        When ``stamp`` takes its next tick, ``(vx, w)`` (m/s, rad/s), held to the drive's speed, turn
        rate and accelerations, goes out on ``drive/target_velocity`` stamped ``stamp``: True; else
        nothing: False. Once it gives up or finishes, zero goes out instead. :class:`BadInput` for a
        velocity that is not finite (nothing goes out); ValueError for a service that does not drive."""
        if self._driving is None:
            raise ValueError(f"{self._service_type.__name__} does not drive (its class attribute drives)")
        return self._driving.drive(stamp, vx, w)

    # --- its end ---

    def finish(self, exit_code: int = 0) -> None:
        """End the service by itself: it stops after this handler; its process exits ``exit_code``
        (in ``invent up``, a service that ends ends the run, as a built-in's death does). A service
        that drives and finishes with 0 ends as the drive does: zero on its next ticks, the outcome
        ``completed``, then exit 0."""
        if self._driving is not None and exit_code == 0:
            self._driving.core.finish(f"{self.name} finished")
            return
        self._on_finish(exit_code)

    # --- the runtime's side ---

    def _start_lockstep(self, lockstep: Lockstep) -> None:
        output = self._outputs.get(lockstep.output)
        if output is None:
            raise ValueError(f"lockstep output {lockstep.output!r} was not declared with ctx.output()")
        if "tm" not in getattr(output.message_type, "__struct_fields__", ()):
            raise ValueError(f"lockstep output {lockstep.output!r}: {output.message_type.__name__} has no tm stamp")
        self._schedule = PeriodicSchedule(lockstep.rate_hz, 0)
        self._node.participate(output._publisher, lockstep.rate_hz, lockstep.output)

    def _start_driving(self, drives: Drives) -> None:
        self._driving = DriveOutput(self._node, self.config, self.name, drives.rate_hz, self._on_finish)

    def _refuse_if_driving(self, what: str) -> None:
        if self._service_type.drives is not None:
            raise ValueError(f"{what}: a service that drives publishes and serves only the drive's keys")

    def _runtime_status(self) -> UserServiceStatus | DriveStatus:
        """The runtime's part of its status (a driving service's: the drive's); the service's own
        ``status()`` is merged over it on the wire."""
        lockstep = self._service_type.lockstep
        participating = None
        if lockstep is not None:
            output = self._outputs[lockstep.output]
            participating = UserLockstep(output=output.key, rate_hz=lockstep.rate_hz, matched=output.matched)
        driving = self._driving
        matched = participating is None or participating.matched
        # the simulator's start handshake: a participant sees it, and its output has a subscriber
        sim_alive = self._sim_alive and matched and (driving is None or driving.publisher.matched)
        sim_time_s = None if self._sim_ns is None else self._sim_ns / NANOSECONDS_PER_SECOND
        outputs = {key: output.published for key, output in self._outputs.items()}
        if driving is not None:
            return msgspec.structs.replace(
                driving.status(sim_alive),
                sim_time_s=sim_time_s,
                lockstep=participating,
                outputs=outputs,
                calls=dict(self._calls),
            )
        return UserServiceStatus(
            sim_alive=sim_alive, sim_time_s=sim_time_s, lockstep=participating, outputs=outputs, calls=dict(self._calls)
        )

    def _on_sim(self, alive: bool) -> None:
        self._sim_alive = alive

    def _on_clock(self, message: TimedDoubleSeq) -> None:
        self._sim_ns = message.tm.to_nanoseconds()

    def _next_wait(self) -> Wait:
        """Run the timers that are due; wait until the next."""
        if not self._timers:
            return Wait()
        now = time.monotonic()
        for timer in self._timers:
            if timer.due <= now:
                timer.due = now + timer.period_s
                self._node.guard("timer", timer.callback)
        return Wait(until=min(timer.due for timer in self._timers))


@dataclass
class _Timer:
    due: float
    """When it runs next (``time.monotonic()``)."""
    period_s: float
    callback: Callable[[], None]


def _error_text(payload: bytes) -> str:
    try:
        value = json.loads(payload)
    except ValueError:
        return payload.decode("utf-8", errors="replace")
    return str(value.get("error", value)) if isinstance(value, dict) else str(value)
