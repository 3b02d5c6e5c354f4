"""Codec benchmark: encode + decode of every message type, the project's codec against stdlib json.

Both sides start from a typed message and end with an equal typed message, so both pay for
the conversion between the Struct and JSON:

- **codec**: ``schemas.codec.encode(message)`` then ``schemas.codec.decode(Type, payload)``
  (typed, strict: finite checks, ranges, unknown fields refused).
- **json**: ``json.dumps(as_dict(message)).encode()`` then ``from_dict(Type, json.loads(payload))``,
  where ``as_dict``/``from_dict`` walk the Struct's fields (nested Structs included) the way
  ``dataclasses.asdict`` and a keyword constructor would; the constructor runs the same
  ``__post_init__`` finite checks, but no type or range validation (so json gets the easier job).
"""

from __future__ import annotations

import json
import statistics
import time
import typing
from collections.abc import Callable
from typing import Any

import msgspec

from schemas.codec import MESSAGE_TYPES, decode, encode
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    BumpEvent,
    NoArguments,
    PDGains,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)

TM = Time(sec=12, nsec=345_000_000)
SAMPLES: dict[type[msgspec.Struct], msgspec.Struct] = {
    Time: TM,
    TimedDoubleSeq: TimedDoubleSeq(tm=TM, data=[0.123456789, -1.23456789]),
    TimedVelocity: TimedVelocity(tm=TM, id=[], vx=0.3, vy=0.0, w=-0.25, error=[]),
    TimedPosition: TimedPosition(tm=TM, id=[], x=1.2345678, y=-0.87654321, theta=0.5, error=[]),
    BumpEvent: BumpEvent(tm=TM, obstacle="box", x=0.9, y=0.01, z=0.1),
    PDGains: PDGains(p_gain_l=5.0, p_gain_r=5.0, d_gain_l=2.0, d_gain_r=2.0),
    NoArguments: NoArguments(),
}
"""One typical message of each type (wheel angles and torques carry two values)."""

TARGET_SECONDS = 0.05
"""Wall time one timed batch aims at."""


def _nested_structs(message_type: type[msgspec.Struct]) -> tuple[tuple[str, type | None], ...]:
    hints = typing.get_type_hints(message_type)
    return tuple(
        (name, hints[name] if isinstance(hints[name], type) and issubclass(hints[name], msgspec.Struct) else None)
        for name in message_type.__struct_fields__
    )


_FIELDS = {message_type: _nested_structs(message_type) for message_type in MESSAGE_TYPES}


def as_dict(message: msgspec.Struct) -> dict[str, Any]:
    return {
        name: as_dict(getattr(message, name)) if nested else getattr(message, name)
        for name, nested in _FIELDS[type(message)]
    }


def from_dict(message_type: type[msgspec.Struct], data: dict[str, Any]) -> msgspec.Struct:
    return message_type(
        **{name: from_dict(nested, data[name]) if nested else data[name] for name, nested in _FIELDS[message_type]}
    )


def codec_round_trip(message: msgspec.Struct) -> msgspec.Struct:
    return decode(type(message), encode(message))


def json_round_trip(message: msgspec.Struct) -> msgspec.Struct:
    return from_dict(type(message), json.loads(json.dumps(as_dict(message)).encode()))


def ns_per_call(function: Callable[[msgspec.Struct], Any], message: msgspec.Struct, repeats: int) -> float:
    """Median over ``repeats`` batches of the mean ns per call (the batch size is calibrated first)."""
    count = 1
    while True:
        started = time.perf_counter_ns()
        for _ in range(count):
            function(message)
        elapsed = time.perf_counter_ns() - started
        if elapsed >= TARGET_SECONDS * NANOSECONDS_PER_SECOND / 4 or count >= 1 << 22:
            break
        count *= 4
    batch = max(1, int(count * TARGET_SECONDS * NANOSECONDS_PER_SECOND / max(elapsed, 1)))
    timings = []
    for _ in range(repeats):
        started = time.perf_counter_ns()
        for _ in range(batch):
            function(message)
        timings.append((time.perf_counter_ns() - started) / batch)
    return statistics.median(timings)


def run(repeats: int = 5) -> dict[str, dict[str, float]]:
    """``{Type: {"codec_ns", "json_ns", "ratio"}}``; ratio = json_ns / codec_ns (how many times faster)."""
    results = {}
    for message_type, message in SAMPLES.items():
        assert codec_round_trip(message) == message == json_round_trip(message), message_type
        codec_ns = ns_per_call(codec_round_trip, message, repeats)
        json_ns = ns_per_call(json_round_trip, message, repeats)
        results[message_type.__name__] = {"codec_ns": codec_ns, "json_ns": json_ns, "ratio": json_ns / codec_ns}
    return results
