"""The localization's rights by ``localization.mode``, least privilege: the stub alone reads a
ground truth (``motor/sim_pose/localization``); amcl and none have no grant on ``sim/body_pose`` nor
``motor/sim_pose/*`` (nor the sim's status, which holds its pose); amcl serves
``localization/initial_pose`` and ``global_localization``, which the operator (``invent localize``)
and the ROS 2 bridge (``/initialpose``: the initial pose only) may query. Checked on the grants, on
the files ``invent secrets`` writes, and through a real secured router: a subscriber declared with
amcl's localization credentials receives nothing of ``sim/body_pose`` while the sim puts it."""

from __future__ import annotations

import json
import queue
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import get_args

import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.navigation import LocalizationReply
from services.config.sections import LocalizationMode
from services.security import Flow, Message, Profile, Role, grants, write_profile
from tests.harness import call, free_port, run_invent, wait_until

KEYS = Keys("secured")
GROUND_TRUTH = (KEYS.sim_body_pose, KEYS.motor_sim_pose_localization, KEYS.motor_sim_pose_gui, KEYS.status(Service.SIM))
MODES: tuple[LocalizationMode, ...] = get_args(LocalizationMode)


def _matching(role: Role, message: Message, flow: Flow, key: str, mode: LocalizationMode = "stub") -> list[str]:
    """The key expressions of ``role``'s grants (for localization mode ``mode``) on which ``message``
    in ``flow`` would be allowed on ``key``: those that intersect it."""
    return [
        expr
        for grant in grants(role, KEYS, localization=mode)
        if message in grant.messages and grant.flow is flow
        for expr in grant.key_exprs
        if zenoh.KeyExpr(expr).intersects(zenoh.KeyExpr(key))
    ]


def _allowed(role: Role, message: Message, flow: Flow, key: str, mode: LocalizationMode = "stub") -> bool:
    return bool(_matching(role, message, flow, key, mode))


@pytest.mark.parametrize("mode", ["amcl", "none"])
def test_amcl_and_none_have_no_grant_on_the_ground_truth(mode):
    for key in GROUND_TRUTH:
        for message, flow in (
            (Message.DECLARE_SUBSCRIBER, Flow.INGRESS),
            (Message.PUT, Flow.EGRESS),
            (Message.QUERY, Flow.INGRESS),
            (Message.REPLY, Flow.EGRESS),
        ):
            assert not _matching(Role.LOCALIZATION, message, flow, key, mode), (mode, key, message, flow)


def test_each_mode_subscribes_exactly_its_inputs():
    inputs = {
        "stub": {KEYS.motor_sim_pose_localization},
        "amcl": {KEYS.sim_scan, KEYS.motor_wheel_angles},
        "none": {KEYS.motor_wheel_angles},
    }
    assert set(inputs) == set(MODES)
    for mode, keys in inputs.items():
        subscribed = {
            expr
            for grant in grants(Role.LOCALIZATION, KEYS, localization=mode)
            if grant.flow is Flow.INGRESS and Message.DECLARE_SUBSCRIBER in grant.messages
            for expr in grant.key_exprs
        }
        assert subscribed == keys, mode
        sent = {
            expr
            for grant in grants(Role.LOCALIZATION, KEYS, localization=mode)
            if grant.flow is Flow.EGRESS and Message.PUT in grant.messages
            for expr in grant.key_exprs
        }
        assert sent == keys, mode
    assert not _allowed(Role.LOCALIZATION, Message.DECLARE_SUBSCRIBER, Flow.INGRESS, KEYS.sim_body_pose, "stub")


def test_the_default_is_the_stub_no_other_service_depends_on_the_mode_and_only_the_tools_read_everything():
    assert grants(Role.LOCALIZATION, KEYS) == grants(Role.LOCALIZATION, KEYS, localization="stub")
    for role in (Role.OBSERVER, Role.ODOMETRY, Role.DRIVE, Role.OPERATOR):
        assert grants(role, KEYS, localization="amcl") == grants(role, KEYS), role
    for role in (Role.OBSERVER, Role.OPERATOR):
        assert _allowed(role, Message.DECLARE_SUBSCRIBER, Flow.INGRESS, KEYS.sim_body_pose), role
    # a service reads what it declares (services/interfaces.py): the ground truth is the motor's input alone
    for role in (Role.ODOMETRY, Role.DRIVE):
        assert not _allowed(role, Message.DECLARE_SUBSCRIBER, Flow.INGRESS, KEYS.sim_body_pose), role
    assert _allowed(Role.MOTOR, Message.DECLARE_SUBSCRIBER, Flow.INGRESS, KEYS.sim_body_pose)


@pytest.mark.parametrize("mode", MODES)
def test_the_localization_puts_its_own_keys_serves_its_status_and_in_amcl_its_queryables(mode):
    assert _allowed(Role.LOCALIZATION, Message.PUT, Flow.INGRESS, KEYS.localization_pose, mode)
    # only the particle filter has particles
    assert _allowed(Role.LOCALIZATION, Message.PUT, Flow.INGRESS, KEYS.localization_particles, mode) == (mode == "amcl")
    assert not _allowed(Role.LOCALIZATION, Message.PUT, Flow.INGRESS, KEYS.odometry_pose, mode)
    assert _allowed(Role.LOCALIZATION, Message.DECLARE_QUERYABLE, Flow.INGRESS, KEYS.status(Service.LOCALIZATION), mode)
    for key in (KEYS.localization_initial_pose, KEYS.localization_global_localization):
        assert _allowed(Role.LOCALIZATION, Message.DECLARE_QUERYABLE, Flow.INGRESS, key, mode) == (mode == "amcl")
    # the liveliness it watches (the sim's token) and its own tokens (alive, lockstep ticks)
    assert _allowed(
        Role.LOCALIZATION, Message.DECLARE_LIVELINESS_SUBSCRIBER, Flow.INGRESS, KEYS.alive(Service.SIM), mode
    )
    assert _allowed(Role.LOCALIZATION, Message.LIVELINESS_TOKEN, Flow.INGRESS, KEYS.alive(Service.LOCALIZATION), mode)
    assert not _allowed(Role.LOCALIZATION, Message.QUERY, Flow.INGRESS, KEYS.status(Service.MOTOR), mode)


def test_the_operator_and_the_bridge_may_give_an_initial_pose_and_no_one_else():
    initial, anywhere = KEYS.localization_initial_pose, KEYS.localization_global_localization
    for role in Role:
        may_query = _allowed(role, Message.QUERY, Flow.INGRESS, initial, "amcl")
        assert may_query == (role in (Role.OPERATOR, Role.ROS2)), role
        assert _allowed(role, Message.QUERY, Flow.INGRESS, anywhere, "amcl") == (role is Role.OPERATOR), role
        if role is not Role.LOCALIZATION:
            assert not _allowed(role, Message.DECLARE_QUERYABLE, Flow.INGRESS, initial, "amcl"), role


def _localization_rules(router_config: Path) -> list[dict]:
    # the file is JSON after its one comment line (services/security/profile.py)
    router = json.loads(router_config.read_text().split("\n", 1)[1])
    rules = router["access_control"]["rules"]
    return [rule for rule in rules if rule["id"].startswith(f"{Role.LOCALIZATION}-")]


def test_invent_secrets_writes_the_rules_of_its_localization_mode(tmp_path):
    result = run_invent("secrets", str(tmp_path / "amcl"), "--robot", KEYS.robot, "--localization-mode", "amcl")
    assert result.returncode == 0, result.stderr
    subscribed = {
        key
        for rule in _localization_rules(tmp_path / "amcl" / "router.json5")
        if "declare_subscriber" in rule["messages"] and rule["flows"] == ["ingress"]
        for key in rule["key_exprs"]
    }
    assert subscribed == {KEYS.sim_scan, KEYS.motor_wheel_angles}
    default = write_profile(tmp_path / "stub", KEYS, endpoint=f"tcp/127.0.0.1:{free_port()}")
    assert any(
        KEYS.motor_sim_pose_localization in rule["key_exprs"] for rule in _localization_rules(default.router_config)
    )
    bad = run_invent("secrets", str(tmp_path / "bad"), "--localization-mode", "gps")
    assert bad.returncode == 2 and "--localization-mode" in bad.stderr


@contextmanager
def _secured_router(
    tmp_path: Path, mode: LocalizationMode
) -> Iterator[tuple[Profile, Callable[[Role], zenoh.Session]]]:
    profile = write_profile(tmp_path / "secrets", KEYS, endpoint=f"tcp/127.0.0.1:{free_port()}", localization=mode)
    with ExitStack() as stack:
        stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.router_config))))

        def open_as(role: Role) -> zenoh.Session:
            return stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.client_config(role)))))

        yield profile, open_as


def _until(received: queue.Queue[str], key: str, timeout: float = 10.0) -> list[str]:
    """What arrives on ``received`` up to and including ``key``; fails after ``timeout`` seconds without it."""
    deadline = time.monotonic() + timeout
    arrived: list[str] = []
    while key not in arrived:
        try:
            arrived.append(received.get(timeout=max(0.0, deadline - time.monotonic())))
        except queue.Empty:
            raise AssertionError(f"no sample of {key} within {timeout} s (only {arrived})") from None
    return arrived


@pytest.mark.parametrize("mode", ["amcl", "stub"])
def test_through_the_router_amcls_localization_receives_no_ground_truth_while_the_sim_and_motor_put_it(tmp_path, mode):
    """The localization's session subscribes the ground truth, the scan and the sim's pose for the
    stub; the sim puts the ground truth then the scan, the motor the sim's pose. In amcl mode, once
    the scan has arrived (one transport per session, in order), the ground truth would have too."""
    with _secured_router(tmp_path, mode) as (_profile, open_as):
        localization = open_as(Role.LOCALIZATION)
        received: queue.Queue[str] = queue.Queue()
        for key in (KEYS.sim_body_pose, KEYS.sim_scan, KEYS.motor_sim_pose_localization):
            localization.declare_subscriber(key, lambda sample: received.put(str(sample.key_expr)))
        sim, motor = open_as(Role.SIM), open_as(Role.MOTOR)
        observer = open_as(Role.OBSERVER)  # a reader every put matches, so that the puts go out
        observer.declare_subscriber(KEYS.everything, lambda _sample: None)
        body_pose, scan = sim.declare_publisher(KEYS.sim_body_pose), sim.declare_publisher(KEYS.sim_scan)
        sim_pose = motor.declare_publisher(KEYS.motor_sim_pose_localization)
        wait_until(lambda: all(p.matching_status.matching for p in (body_pose, scan, sim_pose)), 10, "readers")
        seen: list[str] = []
        for attempt in range(3):
            body_pose.put(b"[0, 0, 0]")
            scan.put(f"{attempt}")
            sim_pose.put(b"[0, 0, 0, 0]")
            if mode == "amcl":  # the scan, put after the ground truth on the same session, closes it
                seen += _until(received, KEYS.sim_scan)
        if mode == "stub":
            # the stub may not read the scan either: its own input, put last; then a query of the sim's,
            # which reaches the localization after everything the sim's session put before it
            seen += _until(received, KEYS.motor_sim_pose_localization)
            barrier = KEYS.status(Service.LOCALIZATION)
            localization.declare_queryable(barrier, lambda query: query.reply(barrier, b"{}"))
            assert call(sim, barrier)[0], "the barrier answered"
        while not received.empty():
            seen.append(received.get_nowait())
    assert KEYS.sim_body_pose not in seen, "the localization may not subscribe the ground truth"
    assert (KEYS.motor_sim_pose_localization in seen) == (mode == "stub"), seen
    assert (KEYS.sim_scan in seen) == (mode == "amcl"), seen


def test_through_the_router_the_operator_and_the_bridge_reach_amcls_initial_pose_and_the_observer_does_not(tmp_path):
    with _secured_router(tmp_path, "amcl") as (_profile, open_as):
        localization = open_as(Role.LOCALIZATION)
        asked: list[str] = []

        def answer(query: zenoh.Query) -> None:
            asked.append(str(query.key_expr))
            query.reply(query.key_expr, encode(LocalizationReply(True)))

        for key in (KEYS.localization_initial_pose, KEYS.localization_global_localization):
            localization.declare_queryable(key, answer)
        callers = {role: open_as(role) for role in (Role.OPERATOR, Role.ROS2, Role.OBSERVER)}
        operator = callers[Role.OPERATOR]
        wait_until(
            lambda: [r for r in operator.get(KEYS.localization_initial_pose, timeout=1.0) if r.ok is not None],
            10,
            "the localization's queryable at the operator",
        )
        asked.clear()
        answered = {}
        for role, session in callers.items():
            for key in (KEYS.localization_initial_pose, KEYS.localization_global_localization):
                replies = [r for r in session.get(key, payload=b"{}", timeout=1.0) if r.ok is not None]
                answered[(role, key)] = len(replies)
    assert answered == {
        (Role.OPERATOR, KEYS.localization_initial_pose): 1,
        (Role.OPERATOR, KEYS.localization_global_localization): 1,
        (Role.ROS2, KEYS.localization_initial_pose): 1,
        (Role.ROS2, KEYS.localization_global_localization): 0,
        (Role.OBSERVER, KEYS.localization_initial_pose): 0,
        (Role.OBSERVER, KEYS.localization_global_localization): 0,
    }
    assert sorted(asked) == sorted(
        [KEYS.localization_initial_pose, KEYS.localization_global_localization, KEYS.localization_initial_pose]
    )
