"""The bad payloads tests/test_fuzz.py sends the running services (hypothesis strategies), each bad
against a baseline that puts every time base at T0 = 10 s: malformed, or well-formed but wrong.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from hypothesis import strategies as st

from schemas.keys import Keys
from schemas.messages import MAX_ID_LENGTH, MAX_SEQUENCE_LENGTH
from services.config import InputConfig, MotorConfig

PAYLOADS_PER_KEY = int(os.environ.get("INVENT_FUZZ_PAYLOADS", "30"))
BATCH = 10
"""Payloads per hypothesis example: more would overrun the data hypothesis draws an example from."""
KEYS = Keys("fuzzed")
SIM_KEYS = Keys("fuzzed-sim")
S = 1_000_000_000
T0 = 10 * S
LIMITS = InputConfig()
HORIZON_NS = round(LIMITS.stamp_horizon * S)
TARGET_HISTORY_NS = round(MotorConfig().command_timeout * S)
BASELINE_TARGET = (0.1, 0.0)
"""The drive runs a constant (0.1, 0) too: its own targets, good input, leave the target as it is."""
BASELINE_LEAD_NS = 500_000_000
IDENTITY_BODY = [0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
FIGURES = Path(os.environ.get("INVENT_FUZZ_FIGURES", "")) if os.environ.get("INVENT_FUZZ_FIGURES") else None

# --- payloads -------------------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
absurd_seconds = st.integers(min_value=10**9, max_value=10**40)
# A stamp the services must refuse against a time base at T0 (or, for torques, the sim's present).
stamp_back = st.integers(min_value=0, max_value=T0)
stamp_far_ahead = st.integers(min_value=T0 + HORIZON_NS + 1, max_value=T0 + 10**6 * S)


def _tm(stamp_ns: int) -> dict[str, int]:
    return {"sec": stamp_ns // S, "nsec": stamp_ns % S}


def _json(value: object) -> bytes:
    return json.dumps(value).encode()


@st.composite
def malformed(draw: st.DrawFn, valid: bytes) -> bytes:
    """Bad whatever the key: never a JSON object of the right shape."""
    kind = draw(st.sampled_from(["bytes", "truncated", "nan", "mistyped", "nested", "unknown_field", "not_object"]))
    if kind == "bytes":
        payload = draw(st.binary(min_size=1, max_size=300))
        return payload if not _is_json_object(payload) else payload + b"}"
    if kind == "truncated":
        return valid[: draw(st.integers(min_value=1, max_value=len(valid) - 1))]
    if kind == "nan":
        literal = draw(st.sampled_from([b"NaN", b"Infinity", b"-Infinity", b"1e999", b"-1e999"]))
        return valid.replace(b"0.0", literal, 1) if b"0.0" in valid else b'{"tm": ' + literal + b"}"
    if kind == "mistyped":
        message = json.loads(valid)
        field = draw(st.sampled_from(sorted(message)))
        message[field] = draw(st.sampled_from(_wrong_types(message[field])))
        return _json(message)
    if kind == "nested":
        depth = draw(st.integers(min_value=10, max_value=100_000))
        return b'{"tm": ' + b"[" * depth + b"]" * depth + b"}"
    if kind == "unknown_field":
        return _json({**json.loads(valid), draw(st.from_regex(r"[a-z][a-z0-9]{0,7}_", fullmatch=True)): 1})
    return _json(draw(st.one_of(st.lists(finite, max_size=5), st.text(max_size=20), st.integers(), st.none())))


def _wrong_types(value: object) -> list[object]:
    """Values of another JSON type than ``value``'s, none of which the field could take (msgspec
    takes an integer for a float, and an empty list is a valid ``id``)."""
    candidates: list[object] = ["x", None, True, {"a": 1}]
    if not isinstance(value, list):
        candidates.append([])
    if not isinstance(value, (int, float)):
        candidates.append(-1)
    return candidates


def _is_json_object(payload: bytes) -> bool:
    try:
        return isinstance(json.loads(payload), dict)
    except ValueError:
        return False


def _seq(stamp_ns: int, data: list[float]) -> bytes:
    return _json({"tm": _tm(stamp_ns), "data": data})


def _absurd_seq(seconds: int, data: list[float]) -> bytes:
    return _json({"tm": {"sec": seconds, "nsec": 0}, "data": data})


@st.composite
def wheel_angles(draw: st.DrawFn) -> bytes:
    """Bad against a time base at T0 with the wheels at 0 (two wheels, ids 0 and 1)."""
    plausible = st.floats(min_value=-1e6, max_value=1e6, exclude_min=True, exclude_max=True)
    pair = st.lists(plausible, min_size=2, max_size=2)
    kind = draw(st.sampled_from(["malformed", "back", "ahead", "absurd", "jump", "short", "long"]))
    if kind == "malformed":
        return draw(malformed(_seq(T0 + 1_000_000, [0.0, 0.0])))
    if kind == "back":
        return _seq(draw(stamp_back), draw(pair))
    if kind == "ahead":
        return _seq(draw(stamp_far_ahead), draw(pair))
    if kind == "absurd":
        return _absurd_seq(draw(absurd_seconds), draw(pair))
    if kind == "jump":
        dt_ns = draw(st.integers(min_value=1, max_value=HORIZON_NS))
        least = LIMITS.max_wheel_speed * dt_ns / S * 1.01 + 1e-6
        jump = draw(st.floats(min_value=least, max_value=1e308)) * draw(st.sampled_from([1.0, -1.0]))
        return _seq(T0 + dt_ns, draw(st.permutations([jump, 0.0])))
    if kind == "short":
        return _seq(T0 + 1_000_000, draw(st.lists(finite, max_size=1)))
    return _seq(T0 + 1_000_000, [0.0] * draw(st.integers(min_value=MAX_SEQUENCE_LENGTH + 1, max_value=5000)))


@st.composite
def body_poses(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["malformed", "length", "back", "ahead", "absurd", "far"]))
    if kind == "malformed":
        return draw(malformed(_seq(T0, IDENTITY_BODY)))
    if kind == "length":
        length = draw(st.integers(min_value=0, max_value=MAX_SEQUENCE_LENGTH).filter(lambda n: n != 12))
        return _seq(T0, [0.0] * length)
    if kind == "back":
        return _seq(T0 - HORIZON_NS - draw(st.integers(min_value=1, max_value=T0 - HORIZON_NS)), IDENTITY_BODY)
    if kind == "ahead":
        return _seq(draw(stamp_far_ahead), IDENTITY_BODY)
    if kind == "absurd":
        return _absurd_seq(draw(absurd_seconds), IDENTITY_BODY)
    x = draw(st.floats(min_value=LIMITS.max_coordinate * 1.001, max_value=1e308)) * draw(st.sampled_from([1, -1]))
    return _seq(T0, [x, *IDENTITY_BODY[1:]])


def _velocity(stamp: dict[str, int], vx: float = 0.1, w: float = 0.0, ids: int = 0, errors: int = 0) -> bytes:
    return _json({"tm": stamp, "id": [1] * ids, "vx": vx, "vy": 0.0, "w": w, "error": [0.0] * errors})


@st.composite
def targets(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["malformed", "old", "ahead", "absurd", "speed", "ids", "errors"]))
    if kind == "malformed":
        return draw(malformed(_velocity(_tm(T0))))
    if kind == "old":
        return _velocity(_tm(T0 - TARGET_HISTORY_NS - draw(st.integers(min_value=1, max_value=T0 - TARGET_HISTORY_NS))))
    if kind == "ahead":
        return _velocity(_tm(draw(stamp_far_ahead)))
    if kind == "absurd":
        return _velocity({"sec": draw(absurd_seconds), "nsec": 0})
    if kind == "speed":
        fastest_plausible = LIMITS.max_wheel_speed * 0.1  # wheel radius 0.1 m
        vx = draw(st.floats(min_value=fastest_plausible * 1.5, max_value=1e300)) * draw(st.sampled_from([1, -1]))
        return _velocity(_tm(T0), vx=vx)
    many = draw(st.integers(min_value=MAX_ID_LENGTH + 1, max_value=100_000))
    return _velocity(_tm(T0), ids=many) if kind == "ids" else _velocity(_tm(T0), errors=many)


def _position(stamp: dict[str, int], x: float = 0.0) -> bytes:
    return _json({"tm": stamp, "id": [], "x": x, "y": 0.0, "theta": 0.0, "error": []})


far_coordinate = st.floats(min_value=LIMITS.max_coordinate * 1.001, max_value=1e308)


@st.composite
def fixes(draw: st.DrawFn) -> bytes:
    """Bad for an odometry whose history is the baseline's samples, from T0 - BASELINE_LEAD_NS to T0
    (or fewer of them: some may have gone by before it subscribed)."""
    kind = draw(st.sampled_from(["malformed", "back", "ahead", "absurd", "far"]))
    if kind == "malformed":
        return draw(malformed(_position(_tm(T0))))
    if kind == "back":
        return _position(_tm(draw(st.integers(min_value=0, max_value=T0 - BASELINE_LEAD_NS - 1))))
    if kind == "ahead":
        return _position(_tm(draw(stamp_far_ahead)))
    if kind == "absurd":
        return _position({"sec": draw(absurd_seconds), "nsec": 0})
    return _position(_tm(T0), x=draw(far_coordinate) * draw(st.sampled_from([1, -1])))


@st.composite
def sim_poses(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["malformed", "length", "back", "ahead", "absurd", "far"]))
    if kind == "malformed":
        return draw(malformed(_seq(T0 + 1_000_000, [0.0, 0.0, 0.0, 0.0])))
    if kind == "length":
        return _seq(T0 + 1_000_000, [0.0] * draw(st.integers(min_value=0, max_value=32).filter(lambda n: n != 4)))
    if kind == "back":
        return _seq(draw(stamp_back), [0.0, 0.0, 0.0, 0.0])
    if kind == "ahead":
        return _seq(draw(stamp_far_ahead), [0.0, 0.0, 0.0, 0.0])
    if kind == "absurd":
        return _absurd_seq(draw(absurd_seconds), [0.0, 0.0, 0.0, 0.0])
    return _seq(T0 + 1_000_000, [draw(far_coordinate), 0.0, 0.0, 0.0])


@st.composite
def torques(draw: st.DrawFn) -> bytes:
    """Bad for a realtime sim of two wheels, whatever its time: wrong lengths, stamps from the future."""
    kind = draw(st.sampled_from(["malformed", "length", "future"]))
    if kind == "malformed":
        return draw(malformed(_seq(0, [0.0, 0.0])))
    if kind == "length":
        return _seq(0, [0.0] * draw(st.integers(min_value=0, max_value=32).filter(lambda n: n != 2)))
    return _absurd_seq(draw(st.integers(min_value=10**6, max_value=10**40)), [20.0, -20.0])


GAIN_NAMES = ("p_gain_l", "p_gain_r", "d_gain_l", "d_gain_r")


@st.composite
def gain_payloads(draw: st.DrawFn) -> bytes:
    gains = dict.fromkeys(GAIN_NAMES, 1.0)
    kind = draw(st.sampled_from(["malformed", "negative", "ceiling", "missing", "empty"]))
    if kind == "malformed":
        return draw(malformed(_json(gains)))
    name = draw(st.sampled_from(GAIN_NAMES))
    if kind == "negative":
        gains[name] = -draw(st.floats(min_value=1e-300, max_value=1e308))
    elif kind == "ceiling":
        gains[name] = draw(st.floats(min_value=LIMITS.max_gain * 1.001, max_value=1e308))
    elif kind == "missing":
        del gains[name]
    else:
        return b""
    return _json(gains)


@st.composite
def no_argument_payloads(draw: st.DrawFn) -> bytes:
    """Anything but an empty payload or ``{}`` (which would run the method)."""
    kind = draw(st.sampled_from(["bytes", "field", "not_object"]))
    if kind == "bytes":
        payload = draw(st.binary(min_size=1, max_size=200).filter(lambda b: b.strip() and not _is_json_object(b)))
        return payload
    if kind == "field":
        return _json({draw(st.text(min_size=1, max_size=10)): draw(st.one_of(finite, st.text(max_size=5)))})
    return _json(draw(st.one_of(st.lists(st.integers(), max_size=3), st.integers(), st.text(max_size=10))))
