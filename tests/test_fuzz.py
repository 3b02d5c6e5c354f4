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
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedVelocity
from schemas.topics import Method, MethodFamily
from tests.fuzz_payloads import (
    BASELINE_LEAD_NS,
    BASELINE_TARGET,
    BATCH,
    FIGURES,
    IDENTITY_BODY,
    KEYS,
    PAYLOADS_PER_KEY,
    SIM_KEYS,
    T0,
    _seq,
    body_poses,
    fixes,
    gain_payloads,
    no_argument_payloads,
    sim_poses,
    targets,
    torques,
    wheel_angles,
)
from tests.harness import InventProcess, peer_session, running_router, wait_alive, wait_until

pytestmark = pytest.mark.slow

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
