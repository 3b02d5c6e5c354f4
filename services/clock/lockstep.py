"""The whole loop in lockstep, pure (no zenoh): who waits for what, so that a lockstep run gives
the same samples, bit for bit, whatever the machine's load and the order zenoh delivers in.

The simulator steps the motor (it waits for each step's torque). The services that output on a
tick grid of their own are stepped too; they are the *participants*:

- A participant holds the liveliness token ``Keys.ticks(service, rate)``. Its ticks are the
  grid ``round(k·1e9/rate)`` ns of simulation time; each is taken by the first stamp at or after
  it (:class:`~services.clock.sim_time.PeriodicSchedule` anchored at 0), and the output is stamped
  with that stamp. The last output of a participant that ends (the drive at the end of its
  scenario) carries the attachment :data:`FINAL`.
- The simulator, at a step that is a tick of a participant, waits for that participant's
  output stamped with the step's time before it steps (:class:`TickBarrier`). A participant
  whose token was there when the simulator started is waited for from its first tick; one that
  comes later, from its first output. It is waited for as long as its token lives, however long
  that takes (a loaded machine only slows the run); one that withdraws its token (it ended or
  died) is dropped at once, and waited for again only once it outputs again.
- Each lockstep step's wheel angles carry a :class:`StepMark` attachment whose ``owed`` says,
  for each participant's output key, the stamp of the newest output the simulator took. A
  consumer takes the sample only once it has taken that output too (:class:`Hold`): the motor
  the drive's target; odometry (the motor passes the attachment on with ``motor/wheel_angles``)
  the localization's fix. Zenoh delivers each link in order but not across links, so without it
  a target could reach the motor before or after the next wheel angles, depending on the
  machine's load.
- Consumers apply an output by its stamp: a target stamped t from the first wheel sample after
  t; a fix stamped t replaces the pose integrated up to t.

The mark also says whether the step is *observed*, in both modes
(:class:`~services.clock.observation.ObservedSteps`): the outputs that are observed rather than
controlled go out at those steps only (docs/protocol.md section 2.7). A realtime simulator's
mark owes nothing: nobody holds anything, nothing waits.
"""

from __future__ import annotations

import collections
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import msgspec

from schemas.codec import BadInput
from schemas.keys import Service, ServiceName
from schemas.messages import NANOSECONDS_PER_SECOND, Time
from schemas.status import LockstepParticipant
from schemas.topics import Topic
from services.clock.sim_time import PeriodicSchedule

SampleT = TypeVar("SampleT")

FINAL = b"invent-final"
"""The attachment of a participant's last output: no tick follows."""

OUTPUTS: dict[Service, Topic] = {
    Service.DRIVE: Topic.DRIVE_TARGET_VELOCITY,
    Service.LOCALIZATION: Topic.LOCALIZATION_POSE,
}
"""What each built-in participant outputs at its ticks; a user service's token names its own
output (:func:`schemas.tokens.parse_participant_key`)."""


class StampedOutput(msgspec.Struct, frozen=True):
    """A user participant's output as the simulator reads it: only its stamp (any other field,
    the service's own, is left alone)."""

    tm: Time


class StepMark(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """The attachment of every step's wheel angles (passed on with ``motor/wheel_angles``).

    ``owed``, in lockstep only (None in realtime): per output key (relative to the robot), the
    stamp in ns of the newest output the simulator took before it published the sample.
    ``observed``: the step is observed, so the outputs observed rather than controlled go out."""

    owed: dict[str, int] | None = None
    observed: bool = False


_MARK_DECODER = msgspec.json.Decoder(StepMark)
_MAX_OWED = len(OUTPUTS)


def encode_mark(owed: dict[Topic, int] | None, observed: bool) -> bytes:
    """A step's attachment: ``owed`` in lockstep (None in realtime), and whether it is observed."""
    return msgspec.json.encode(
        StepMark(None if owed is None else {str(topic): stamp for topic, stamp in owed.items()}, observed)
    )


def decode_mark(attachment: bytes | None, stamp_ns: int) -> StepMark | None:
    """The mark of a sample stamped ``stamp_ns``; None without an attachment (a stream that is not
    the simulator's: replayed, or made by hand).

    Raises BadInput for an attachment that is not a :class:`StepMark`, or that owes an output
    stamped at or after the sample (an output is always for an earlier step).
    """
    if attachment is None:
        return None
    mark, newest_ns = _parse_mark(attachment)
    if mark.owed and newest_ns >= stamp_ns:
        key = max(mark.owed, key=mark.owed.__getitem__)
        raise BadInput(f"lockstep attachment owes {key} stamped {newest_ns} ns, not before the sample ({stamp_ns} ns)")
    return mark


def decode_owed(attachment: bytes | None, stamp_ns: int) -> dict[str, int] | None:
    """The outputs a sample stamped ``stamp_ns`` is owed; None in realtime or without an attachment."""
    mark = decode_mark(attachment, stamp_ns)
    return None if mark is None else mark.owed


def observed(mark: StepMark | None) -> bool:
    """Whether a sample's step is observed: the simulator's mark says so; a sample without one (a
    replayed or hand-made stream) always is, as every sample was before steps were marked."""
    return mark is None or mark.observed


@functools.lru_cache(maxsize=8)
def _parse_mark(attachment: bytes) -> tuple[StepMark, int]:
    """(mark, the newest stamp it owes), kept for the last few attachments: a step's mark changes
    only at a participant's tick or an observed step, and every step's sample carries one.
    Callers must not mutate it."""
    try:
        mark = _MARK_DECODER.decode(attachment)
    except (msgspec.DecodeError, UnicodeDecodeError) as error:  # msgspec raises the latter for a string not UTF-8
        raise BadInput(f"step attachment: {error}") from None
    owed = mark.owed or {}
    if len(owed) > _MAX_OWED:
        raise BadInput(f"lockstep attachment owes {len(owed)} outputs, at most {_MAX_OWED} exist")
    return mark, max(owed.values(), default=-1)


class Hold(Generic[SampleT]):
    """A consumer's side of the protocol for one output (the motor: the drive's target).

    Every sample goes through :meth:`offer`, every output taken through :meth:`took`; ``take``
    handles the samples, in order, each once it owes nothing. At most ``capacity`` samples wait:
    beyond, the oldest is taken all the same. The motor holds one (a second sample means the
    simulator gave up waiting for the first's torque and stepped on); odometry holds many, since
    the motor answers the simulator, and so more samples come, whether odometry is waiting or not.

    A sample taken at once, in :meth:`offer` (every sample, while nothing is owed), is handed to
    ``take`` directly: what it raises reaches the caller, whose input handler counts it. A held
    sample is taken later, by :meth:`took` or behind others, through ``guard(take, sample)`` (the
    node's: it counts what ``take`` raises), so one bad sample never keeps back those after it.
    """

    def __init__(
        self,
        output: Topic,
        take: Callable[[SampleT], None],
        capacity: int,
        guard: Callable[[Callable[[SampleT], None], SampleT], None] | None = None,
    ) -> None:
        self.output = output
        self._take = take
        self._take_released = take if guard is None else functools.partial(guard, take)
        self._capacity = capacity
        self.taken_ns: int | None = None
        """The stamp of the newest output taken."""
        self.holds = 0
        """Samples held for an output."""
        self.overflows = 0
        """Samples taken without their output because ``capacity`` samples waited."""
        self._held: collections.deque[tuple[SampleT, dict[str, int] | None]] = collections.deque()

    def offer(self, sample: SampleT, owed: dict[str, int] | None) -> None:
        """Take ``sample`` now, or hold it while it (or a sample before it) is owed an output."""
        if not self._held:
            # _owes, inline: this runs for every sample, and nearly every one owes nothing.
            needed = None if owed is None else owed.get(self.output)
            if needed is None or (self.taken_ns is not None and self.taken_ns >= needed):
                self._take(sample)
                return
        self._held.append((sample, owed))
        if self._owes(owed):
            self.holds += 1
        self._release()

    @property
    def holding(self) -> bool:
        """True while a sample waits for its output."""
        return bool(self._held)

    def took(self, stamp_ns: int) -> None:
        if self.taken_ns is None or stamp_ns > self.taken_ns:
            self.taken_ns = stamp_ns
        self._release()

    def forget(self) -> None:
        """A new time base (a restarted simulator): stamps start again; held samples are dropped."""
        self.taken_ns = None
        self._held.clear()

    def _release(self) -> None:
        held = self._held
        while held:
            overflow = len(held) > self._capacity
            if not overflow and self._owes(held[0][1]):
                return
            self.overflows += overflow
            self._take_released(held.popleft()[0])

    def _owes(self, owed: dict[str, int] | None) -> bool:
        needed = None if owed is None else owed.get(self.output)
        return needed is not None and (self.taken_ns is None or self.taken_ns < needed)


@dataclass
class _Participant:
    rate_hz: float
    output: str
    """The key (relative to the robot) of its output at its ticks."""
    schedule: PeriodicSchedule | None
    """Its ticks after the present; None while it is not waited for (it joins when it outputs)."""
    taken_ns: int | None = None
    final: bool = False


MAX_PARTICIPANTS = 32
"""Lockstep participants one robot's steps wait for at most: the drive, the localization and user
services (docs/protocol.md section 10.1)."""


class TickBarrier:
    """The simulator's side: which participants' outputs a step must wait for.

    Per step, in order: :meth:`ticks` (the participants with a tick at this step), then
    :meth:`missing` until it is empty (each :meth:`took` output may complete it, each
    :meth:`withdraw` too), or :meth:`gave_up` on those a step does not wait for (their robot's
    motor control has gone); :meth:`owed` is the next step's attachment.
    """

    def __init__(self) -> None:
        self._participants: dict[ServiceName, _Participant] = {}
        self._awaited: dict[ServiceName, int] = {}
        self._next_tick_ns: float = -1
        """No participant has a tick before this stamp: :meth:`ticks` answers the steps between at
        once (it runs at every step, ticks come every few dozen). -1 when a schedule has changed."""

    def announce(self, service: ServiceName, rate_hz: float, *, from_start: bool, output: str | None = None) -> bool:
        """A participant's token appeared: ``from_start`` (before the first step) it is waited for
        from its first tick; otherwise from its first output. ``output``: the key (relative to the
        robot) it outputs on, a user service's; a built-in's is :data:`OUTPUTS`'. False (not a
        participant) for a new one beyond :data:`MAX_PARTICIPANTS`: tokens from a buggy or hostile
        peer must not grow what every step looks at without bound."""
        if output is None:
            if not isinstance(service, Service) or service not in OUTPUTS:
                raise ValueError(f"participant {service}: its output is not known")
            output = str(OUTPUTS[service])
        known = self._participants.get(service)
        if known is not None and known.rate_hz == rate_hz and known.output == output:
            return True
        if known is None and len(self._participants) >= MAX_PARTICIPANTS:
            return False
        schedule = PeriodicSchedule(rate_hz, 0) if from_start else None
        self._participants[service] = _Participant(rate_hz, output, schedule)
        self._next_tick_ns = -1
        return True

    def output(self, service: ServiceName) -> str:
        """The key (relative to the robot) of ``service``'s output at its ticks."""
        participant = self._participants.get(service)
        if participant is not None:
            return participant.output
        return str(OUTPUTS[service]) if isinstance(service, Service) and service in OUTPUTS else str(service)

    def withdraw(self, service: ServiceName) -> bool:
        """Its token went (it ended or died): never waited for again. True if it was known."""
        self._awaited.pop(service, None)
        return self._participants.pop(service, None) is not None

    def took(self, service: ServiceName, stamp_ns: int, now_ns: int, *, final: bool = False) -> None:
        """An output of ``service`` stamped ``stamp_ns`` arrived while the present is ``now_ns``.

        Raises BadInput for one stamped after the present: no tick of it has come yet."""
        if stamp_ns > now_ns:
            raise BadInput(f"{self.output(service)} stamped {stamp_ns} ns, after the present ({now_ns} ns)")
        participant = self._participants.get(service)
        if participant is None:
            return
        if participant.taken_ns is None or stamp_ns > participant.taken_ns:
            participant.taken_ns = stamp_ns
        if participant.schedule is None:
            # Waited for from its first tick after the present: a tick between its output and the
            # present it would never answer (it may not even see that step's clock), and the wait
            # for it would last as long as the participant lives.
            participant.schedule = PeriodicSchedule(participant.rate_hz, 0)
            participant.schedule.due(max(stamp_ns, now_ns))
            self._next_tick_ns = -1
        participant.final = participant.final or final

    def ticks(self, now_ns: int) -> list[ServiceName]:
        """The participants with a tick at ``now_ns`` (call once per step, steps in order)."""
        if now_ns < self._next_tick_ns:
            return []
        due = []
        next_tick_ns = math.inf
        for service, participant in self._participants.items():
            schedule = participant.schedule
            if schedule is None or participant.final:
                continue
            if schedule.due(now_ns):
                self._awaited[service] = now_ns
                due.append(service)
            next_tick_ns = min(next_tick_ns, schedule.next_ns)
        self._next_tick_ns = next_tick_ns
        return due

    def missing(self) -> list[ServiceName]:
        """The participants whose output for their tick at this step has not arrived yet."""
        done = [
            service
            for service, tick_ns in self._awaited.items()
            if (taken := self._participants[service].taken_ns) is not None and taken >= tick_ns
        ]
        for service in done:
            del self._awaited[service]
        return list(self._awaited)

    def gave_up(self, service: ServiceName) -> None:
        """Its output is not waited for at this tick: it is waited for again once it outputs again."""
        self._awaited.pop(service, None)
        participant = self._participants.get(service)
        if participant is not None:
            participant.schedule = None
            self._next_tick_ns = -1

    def announced(self, service: ServiceName) -> bool:
        return service in self._participants

    def waited_for(self) -> list[ServiceName]:
        """The participants whose ticks are waited for."""
        return [service for service, participant in self._participants.items() if participant.schedule is not None]

    def final(self, service: ServiceName) -> bool:
        """True once ``service``'s last output (:data:`FINAL`) has been taken."""
        participant = self._participants.get(service)
        return participant is not None and participant.final

    def owed(self) -> dict[Topic, int]:
        """For the next step's attachment: the newest output taken of each built-in participant
        (a user participant's output is waited for, but no consumer of the loop holds for it)."""
        return {
            OUTPUTS[service]: participant.taken_ns
            for service, participant in self._participants.items()
            if participant.taken_ns is not None and isinstance(service, Service) and service in OUTPUTS
        }

    def status(self) -> dict[str, LockstepParticipant]:
        return {
            str(service): LockstepParticipant(
                rate_hz=participant.rate_hz,
                output=participant.output,
                waited_for=participant.schedule is not None and not participant.final,
                last_output_s=None if participant.taken_ns is None else participant.taken_ns / NANOSECONDS_PER_SECOND,
                final=participant.final,
            )
            for service, participant in self._participants.items()
        }
