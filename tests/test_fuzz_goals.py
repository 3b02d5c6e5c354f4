"""Fuzzing the newer surfaces of a running stack, as an attacker from outside would: the drive's goal
queryables (``drive/goal/send``, ``drive/goal/cancel``), the simulator's sensors (``sim/scan``,
``sim/imu``) and the NavigateToPose action's three services (``send_goal``, ``cancel_goal``,
``get_result``) and ``goal_pose``, in rmw_zenoh's wire format (tests/ros_client.py). Every payload
must be refused and counted by each service that takes the key (``bad_input.by_key``; a goal or a
cancel the drive refuses in its ``goals`` counters), with no internal error, every service alive,
and a goal must still complete afterwards.

One ``invent up --goals --ros2 --composed`` on the kinematic engine (the surfaces are the point, not
the physics). Every generated payload is bad by construction: malformed (random bytes, truncated or
mistyped JSON or CDR, NaN and Infinity literals, unknown fields, strings that are not UTF-8, arrays
beyond their caps) or well-formed but refused (a time limit that overflows a conversion, an id
ending in a newline, a frame or a coordinate out of bounds, scans and IMU samples that cannot be
one, a pose not finite or with no rotation, rmw_zenoh attachments that are not one).

``make test`` sends a few dozen payloads per surface; ``make fuzz`` sets ``INVENT_FUZZ_PAYLOADS``
to 10^4 and writes the figures (payloads and wall time per surface) next to ``INVENT_FUZZ_FIGURES``
(``runs/fuzz-goals.json``).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from schemas.keys import Keys, Service
from tests import ros_client, ros_services
from tests.fuzz_payloads import BATCH, PAYLOADS_PER_KEY
from tests.harness import REPO, free_port, invent_command, peer_session, wait_alive, wait_until
from tests.hostile_payloads import (
    Call,
    cancel_goal_calls,
    cancel_requests,
    get_result_calls,
    goal_pose_samples,
    goal_requests,
    imu_samples,
    scans,
    send_goal_calls,
)

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

KEYS = Keys()
ACTION = "/navigate_to_pose"
STARTUP_TIMEOUT_S = 90.0
FIGURES = (
    Path(os.environ["INVENT_FUZZ_FIGURES"]).with_name("fuzz-goals.json")
    if os.environ.get("INVENT_FUZZ_FIGURES")
    else None
)

Counted = tuple[Service, Callable[[dict[str, Any]], int]]
"""A service that must count each payload, and how its status counts them."""


def bad_input_on(key: str) -> Callable[[dict[str, Any]], int]:
    def count(status: dict[str, Any]) -> int:
        entry = status["bad_input"]["by_key"].get(key)
        return entry["count"] if entry else 0

    return count


def goals_counter(name: str) -> Callable[[dict[str, Any]], int]:
    return lambda status: status["goals"][name]


@dataclass(frozen=True)
class Surface:
    """One key to fuzz: its payloads, who must count each one, and, for a queryable, how its reply
    says it refused (an error reply always does)."""

    name: str
    key: str
    payloads: st.SearchStrategy[Any]
    counted_by: tuple[Counted, ...]
    refusal: Callable[[bytes], bool] | None = None
    """None: a key published to, not queried."""
    ros: bool = False
    """Payloads are :data:`Call` (CDR with an attachment), not bare JSON."""

    def refused(self, reply: zenoh.Reply) -> bool:
        assert self.refusal is not None
        return reply.ok is None or self.refusal(reply.ok.payload.to_bytes())


SCAN_CONSUMERS = (Service.MOTOR, Service.DRIVE, Service.ROS2)
"""Who takes ``sim/scan`` in goal mode: the collision monitor, the costmap, the bridge's ``/scan``."""
NAVIGATE = ros_services.NAVIGATE


def _ros(endpoint: str, payloads: st.SearchStrategy[Call], refusal: Callable[[bytes], bool]) -> Surface:
    key = ros_services.action_key(0, ACTION, endpoint)
    return Surface(f"NavigateToPose {endpoint}", key, payloads, ((Service.ROS2, bad_input_on(key)),), refusal, True)


GOAL_POSE_KEY = ros_client.topic_key(0, "goal_pose", "geometry_msgs/msg/PoseStamped")
SURFACES = [
    Surface(
        "drive/goal/send",
        KEYS.drive_goal_send,
        goal_requests(),
        ((Service.DRIVE, goals_counter("rejected")),),
        lambda reply: not json.loads(reply)["accepted"],
    ),
    Surface(
        "drive/goal/cancel",
        KEYS.drive_goal_cancel,
        cancel_requests(),
        ((Service.DRIVE, goals_counter("cancel_rejected")),),
        lambda reply: json.loads(reply)["canceling"] == [],
    ),
    Surface("sim/scan", KEYS.sim_scan, scans(), tuple((s, bad_input_on(KEYS.sim_scan)) for s in SCAN_CONSUMERS)),
    Surface("sim/imu", KEYS.sim_imu, imu_samples(), ((Service.ROS2, bad_input_on(KEYS.sim_imu)),)),
    _ros(
        "send_goal",
        send_goal_calls(),
        lambda reply: not ros_services.action_decode(reply, f"{NAVIGATE}_SendGoal_Response").accepted,
    ),
    _ros(
        "cancel_goal",
        cancel_goal_calls(),
        lambda reply: ros_services.action_decode(reply, "action_msgs/srv/CancelGoal_Response").return_code == 1,
    ),
    _ros(
        "get_result",
        get_result_calls(),
        lambda reply: ros_services.action_decode(reply, f"{NAVIGATE}_GetResult_Response").status == 0,
    ),
    Surface("goal_pose", GOAL_POSE_KEY, goal_pose_samples(), ((Service.ROS2, bad_input_on(GOAL_POSE_KEY)),), ros=True),
]


class Stack:
    """The running stack and this test's session."""

    def __init__(self, session: zenoh.Session, up: subprocess.Popen[bytes]) -> None:
        self.session = session
        self.up = up
        self.sent: dict[str, int] = {}
        self.wall_s: dict[str, float] = {}
        self._queriers: dict[str, zenoh.Querier] = {}

    def status(self, service: Service) -> dict[str, Any]:
        key = KEYS.status(service)
        querier = self._queriers.get(key)
        if querier is None:
            querier = self._queriers[key] = self.session.declare_querier(key, timeout=5.0)
            wait_until(lambda: querier.matching_status.matching, 10.0, f"a queryable on {key}")
        replies = list(querier.get())
        assert len(replies) == 1 and replies[0].ok is not None, (key, [str(reply.err) for reply in replies])
        return json.loads(replies[0].ok.payload.to_bytes())

    def counts(self, surface: Surface) -> list[int]:
        return [count(self.status(service)) for service, count in surface.counted_by]

    def send(self, surface: Surface, payloads: list[Any]) -> None:
        expected = [count + len(payloads) for count in self.counts(surface)]
        self.sent[surface.name] = self.sent.get(surface.name, 0) + len(payloads)
        calls: list[Call] = payloads if surface.ros else [(payload, None) for payload in payloads]
        if surface.refusal is not None:
            # A batch in flight at once, each answered once: refused (an error, or a refusal the type says).
            pending = [
                self.session.get(surface.key, payload=payload, attachment=attachment, timeout=5.0)
                for payload, attachment in calls
            ]
            for (payload, _), replies in zip(calls, pending, strict=True):
                answered = list(replies)
                assert len(answered) == 1, (surface.name, payload[:200])
                assert surface.refused(answered[0]), (surface.name, payload[:200])
        else:
            for payload, attachment in calls:
                self.session.put(surface.key, payload, attachment=attachment)
        wait_until(lambda: self.counts(surface) == expected, 20.0, f"{surface.name} to count {expected}")


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    directory: Path = tmp_path_factory.mktemp("fuzz-goals")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    flags = ["--goals", "--ros2", "--composed", "--engine", "kinematic", "--no-record", "--listen", endpoint]
    with (directory / "up.log").open("w") as log:
        up = subprocess.Popen(
            invent_command("up", *flags, "--set", "sim.world=empty"), cwd=REPO, stdout=log, stderr=subprocess.STDOUT
        )
        try:
            with peer_session(endpoint) as session:
                for service in Service:
                    wait_alive(session, KEYS.alive(service), STARTUP_TIMEOUT_S)
                fuzzed = Stack(session, up)
                wait_until(
                    lambda: fuzzed.status(Service.ROS2)["navigate"]["drive_serves_goals"],
                    STARTUP_TIMEOUT_S,
                    "the drive's goals",
                )
                yield fuzzed
        finally:
            up.send_signal(2)
            try:
                up.wait(60)
            except subprocess.TimeoutExpired:
                up.kill()
    assert up.returncode == 0, (directory / "up.log").read_text()[-3000:]


def _alive_and_sound(stack: Stack) -> None:
    assert stack.up.poll() is None, "invent up ended"
    for service in Service:
        status = stack.status(service)
        assert status["internal_errors"] == 0, (service, status["internal_errors"])


@pytest.mark.parametrize("surface", SURFACES, ids=[surface.name for surface in SURFACES])
def test_bad_payloads_are_refused_counted_and_harmless(stack: Stack, surface: Surface) -> None:
    started = time.monotonic()

    # A failing batch is reported as it is: shrinking it against a live stack took minutes.
    @settings(
        max_examples=max(1, PAYLOADS_PER_KEY // BATCH),
        deadline=None,
        database=None,
        phases=[Phase.generate],
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(payloads=st.lists(surface.payloads, min_size=BATCH, max_size=BATCH))
    def fuzz(payloads: list[Any]) -> None:
        stack.send(surface, payloads)

    while stack.sent.get(surface.name, 0) < PAYLOADS_PER_KEY:
        fuzz()
    stack.wall_s[surface.name] = round(time.monotonic() - started, 1)
    drive = stack.status(Service.DRIVE)["goals"]
    assert (drive["accepted"], drive["running"], drive["pending"]) == (0, None, None), "no goal got through"
    _alive_and_sound(stack)


def test_a_goal_completes_after_the_fuzz(stack: Stack) -> None:
    """Through the whole path: a ROS client's goal, the bridge, the drive; the result SUCCEEDED."""
    client = ros_services.ActionClient(stack.session, ACTION)
    uuid, reply = client.send_goal(1.0, 0.5, math.pi / 2)
    assert reply.response.accepted, stack.status(Service.ROS2)["navigate"]
    result = client.get_result(uuid, timeout=120.0).response
    assert result.status == ros_services.STATUS_CODES["succeeded"], result
    assert stack.status(Service.DRIVE)["goals"]["completed"] == 1
    _alive_and_sound(stack)


def test_fuzz_figures(stack: Stack) -> None:
    """What ``make fuzz`` reports of these surfaces: payloads and wall time per surface."""
    figures = {"payloads": dict(sorted(stack.sent.items())), "wall_s": dict(sorted(stack.wall_s.items()))}
    print("\nfuzz figures (goal, sensor and action surfaces):", json.dumps(figures, indent=2))
    if FIGURES is not None:
        FIGURES.write_text(json.dumps(figures, indent=2) + "\n")
    assert set(figures["payloads"]) == {surface.name for surface in SURFACES}
