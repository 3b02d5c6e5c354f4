"""Fuzzing the running services: generated bad payloads on every key a service consumes and every
queryable it serves. Every service must stay alive, count each bad payload where it is bad input,
and change nothing: the motor's state, gains and target, the odometry's pose.

The services are real processes: motor, odometry, localization and drive of one robot, fed by
this test as their simulator, and a realtime sim of another robot (with no motor, so its only
input is ``motor/torque``). A baseline puts every time base at T0 = 10 s; every generated payload
is bad against it, by construction: malformed (random bytes, truncated or mistyped JSON, NaN and
Infinity literals, deep nesting, arrays beyond the schema's caps, missing or unknown fields) or
well-formed but wrong (stamps back, far ahead, absurd; implausible wheel-angle jumps, velocities,
coordinates and gains; wrong lengths).

``make test`` sends a few hundred payloads; ``make fuzz`` sets ``INVENT_FUZZ_PAYLOADS`` to 10^4 per
key and writes the figures (payloads per key, peak memory of each service) to
``INVENT_FUZZ_FIGURES``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import MAX_ID_LENGTH, MAX_SEQUENCE_LENGTH, Time, TimedVelocity
from schemas.topics import Method, MethodFamily
from services.config import InputConfig, MotorConfig
from tests.harness import InventProcess, peer_session, running_router, wait_alive, wait_until

pytestmark = pytest.mark.slow

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


# --- the running services --------------------------------------------------------------------------


@dataclass(frozen=True)
class Target:
    """One key or queryable to fuzz: who must count each payload, and how they take it."""

    name: str
    key: str
    consumer: Service
    counted_on: Keys
    payloads: st.SearchStrategy[bytes]
    one_at_a_time: bool = False
    """A newest-only or sampled input: a payload overwritten before it is taken is never seen."""
    query: bool = False


TARGETS = [
    Target("motor: sim/wheel_angles", KEYS.sim_wheel_angles, Service.MOTOR, KEYS, wheel_angles()),
    Target("motor: sim/body_pose", KEYS.sim_body_pose, Service.MOTOR, KEYS, body_poses()),
    Target("motor: drive/target_velocity", KEYS.drive_target_velocity, Service.MOTOR, KEYS, targets(), True),
    Target("odometry: motor/wheel_angles", KEYS.motor_wheel_angles, Service.ODOMETRY, KEYS, wheel_angles()),
    Target("odometry: localization/pose", KEYS.localization_pose, Service.ODOMETRY, KEYS, fixes()),
    Target(
        "localization: motor/sim_pose/localization",
        KEYS.motor_sim_pose_localization,
        Service.LOCALIZATION,
        KEYS,
        sim_poses(),
        True,
    ),
    Target("sim: motor/torque", SIM_KEYS.motor_torque, Service.SIM, SIM_KEYS, torques()),
    *(
        Target(
            f"motor: {family}/{method}",
            KEYS.method(family, method),
            Service.MOTOR,
            KEYS,
            gain_payloads() if method is Method.SET_PD_GAIN else no_argument_payloads(),
            query=True,
        )
        for family in MethodFamily
        for method in Method
    ),
]
STATUS_TARGETS = [(KEYS, service) for service in (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION, Service.DRIVE)]
STATUS_TARGETS.append((SIM_KEYS, Service.SIM))


class Loop:
    """The fuzzed services and this test's session, at the baseline."""

    def __init__(self, session: zenoh.Session, processes: dict[Service, InventProcess]) -> None:
        self.session = session
        self.processes = processes
        self.sent: dict[str, int] = {}
        self._status_queriers: dict[str, zenoh.Querier] = {}
        """One per status key for the whole fuzz. With a querier declared and undeclared for each
        of the ~20,000 status reads, each of three full runs lost one read after 60,000 to 75,000
        queries (0 replies though the querier had matched), and the motor answered the next read
        at once, with no event dropped."""

    def status(self, keys: Keys, service: Service) -> dict:
        key = keys.status(service)
        querier = self._status_queriers.get(key)
        if querier is None:
            querier = self._status_queriers[key] = self.session.declare_querier(key, timeout=5.0)
            wait_until(lambda: querier.matching_status.matching, 5.0, f"a queryable on {key}")
        replies = list(querier.get())
        assert len(replies) == 1 and replies[0].ok is not None, (key, [str(reply.err) for reply in replies])
        return json.loads(replies[0].ok.payload.to_bytes())

    def counted(self, target: Target) -> int:
        entry = self.status(target.counted_on, target.consumer)["bad_input"]["by_key"].get(target.key)
        return entry["count"] if entry else 0

    def state(self) -> dict:
        motor = self.status(KEYS, Service.MOTOR)
        return {
            "motor": {name: motor[name] for name in ("state", "gains", "target")},
            "odometry": self.status(KEYS, Service.ODOMETRY)["pose"],
        }

    def send(self, target: Target, payloads: list[bytes]) -> None:
        before = self.counted(target)
        self.sent[target.name] = self.sent.get(target.name, 0) + len(payloads)
        if target.query:
            # A batch in flight at once: an idle service takes posted queries at its waker's pace.
            pending = [(payload, self.session.get(target.key, payload=payload, timeout=5.0)) for payload in payloads]
            for payload, handler in pending:
                replies = list(handler)
                assert len(replies) == 1 and replies[0].err is not None, (target.name, payload[:200])
            assert self.counted(target) == before + len(payloads), target.name
            return
        batches = [[payload] for payload in payloads] if target.one_at_a_time else [payloads]
        for batch in batches:
            for payload in batch:
                self.session.put(target.key, payload)
            before += len(batch)
            wait_until(lambda expected=before: self.counted(target) == expected, 20, f"{target.name} to count it")


@pytest.fixture(scope="module")
def loop() -> Iterator[Loop]:
    with running_router() as endpoint, peer_session(endpoint) as session:
        connect = ("--connect", endpoint)
        robot = ("--robot", KEYS.robot)
        # Drained: each logs a line per second per fuzzed key, for as long as the fuzz runs.
        processes = {
            Service.MOTOR: InventProcess("motor", *connect, *robot, drain=True),
            Service.ODOMETRY: InventProcess("odometry", *connect, *robot, drain=True),
            Service.LOCALIZATION: InventProcess("localization", *connect, *robot, drain=True),
            Service.DRIVE: InventProcess(
                "drive", *connect, *robot, "--for", "3600", "--vx", str(BASELINE_TARGET[0]), drain=True
            ),
            Service.SIM: InventProcess("sim", *connect, "--robot", SIM_KEYS.robot, "--mode", "realtime", drain=True),
        }
        try:
            for keys, service in STATUS_TARGETS:
                wait_alive(session, keys.alive(service), 60)
            fuzzed = Loop(session, processes)
            for key in (KEYS.sim_wheel_angles, KEYS.sim_body_pose, KEYS.drive_target_velocity):
                publisher = session.declare_publisher(key)
                wait_until(lambda p=publisher: p.matching_status.matching, 10, f"a subscriber on {key}")
                publisher.undeclare()
            # Samples every ms up to T0, wheels still, until the localization's first fix is out:
            # it starts only once its publisher matches odometry, which takes a moment after start.
            stamp_ns = T0 - BASELINE_LEAD_NS

            def step_towards_t0() -> bool:
                nonlocal stamp_ns
                stamp_ns = min(stamp_ns + 1_000_000, T0)
                session.put(KEYS.sim_wheel_angles, _seq(stamp_ns, [0.0, 0.0]))
                session.put(KEYS.sim_body_pose, _seq(stamp_ns, IDENTITY_BODY))
                return stamp_ns == T0 and fuzzed.status(KEYS, Service.LOCALIZATION)["fixes_published"] >= 1

            wait_until(step_towards_t0, 30, "the localization's first fix")
            session.put(
                KEYS.drive_target_velocity,
                encode(TimedVelocity(Time.from_nanoseconds(T0), [], BASELINE_TARGET[0], 0.0, BASELINE_TARGET[1], [])),
            )
            wait_until(
                lambda: (
                    fuzzed.status(KEYS, Service.MOTOR)["target"] == dict(zip(("vx", "w"), BASELINE_TARGET))
                    and fuzzed.status(KEYS, Service.ODOMETRY)["counters"]["localization_resets"] >= 1
                ),
                30,
                "the baseline",
            )
            yield fuzzed
            for process in processes.values():
                code, _out, err = process.stop()
                assert code == 0, err
        finally:
            for process in processes.values():
                process.__exit__()


def _peak_rss_mb(pid: int) -> float:
    line = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmHWM"))
    return int(line.split()[1]) / 1024


@pytest.mark.parametrize("target", TARGETS, ids=[target.name for target in TARGETS])
def test_bad_payloads_are_counted_and_change_nothing(loop: Loop, target: Target) -> None:
    before = loop.state()

    @settings(
        max_examples=max(1, PAYLOADS_PER_KEY // BATCH),
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(payloads=st.lists(target.payloads, min_size=BATCH, max_size=BATCH))
    def fuzz(payloads: list[bytes]) -> None:
        loop.send(target, payloads)

    # Hypothesis may run fewer examples than asked (it discards those whose data overran its
    # buffer): go on until this key has had its share.
    while loop.sent.get(target.name, 0) < PAYLOADS_PER_KEY:
        fuzz()
    assert loop.state() == before
    for keys, service in STATUS_TARGETS:
        assert loop.processes[service].process.poll() is None, f"{service} died"
        assert loop.status(keys, service)["internal_errors"] == 0, service


def test_status_queryables_answer_whatever_the_payload(loop: Loop) -> None:
    payloads = [b"", b"\x00\xff", b"{", b'{"a": NaN}', b"[" * 10_000, b"x" * 100_000]
    for keys, service in STATUS_TARGETS:
        for payload in payloads:
            replies = list(loop.session.get(keys.status(service), payload=payload, timeout=5.0))
            assert len(replies) == 1 and replies[0].ok is not None, (service, payload[:20])


def test_fuzz_figures(loop: Loop) -> None:
    """The figures of the run so far (``make fuzz`` prints them): payloads per key, peak memory."""
    figures = {
        "payloads_per_key": dict(sorted(loop.sent.items())),
        "peak_rss_mb": {str(s): round(_peak_rss_mb(p.process.pid), 1) for s, p in loop.processes.items()},
        "alive": {str(s): p.process.poll() is None for s, p in loop.processes.items()},
    }
    print("\nfuzz figures:", json.dumps(figures, indent=2))
    if FIGURES is not None:
        FIGURES.write_text(json.dumps(figures, indent=2) + "\n")
    assert all(figures["alive"].values())
