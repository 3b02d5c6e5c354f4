"""Looking never acts: wildcard queries reach no Motor method, and services listen on loopback only."""

from __future__ import annotations

import ipaddress
import json
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from schemas.keys import Keys, Service
from schemas.topics import Method, MethodFamily
from tests.harness import InventProcess, call, free_port, peer_session, wait_alive, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys("inspected")
ROBOT_FLAGS = ("--robot", KEYS.robot)
TARGET = {"vx": 0.2, "w": 0.1}
METHOD_KEYS = {KEYS.method(family, method) for family in MethodFamily for method in Method}
ABSURD_GAINS = json.dumps({"p_gain_l": 999.0, "p_gain_r": 999.0, "d_gain_l": 999.0, "d_gain_r": 999.0})
WILDCARDS = (
    KEYS.everything,
    f"{KEYS.prefix}/motor/**",
    "invent/**",
    f"{KEYS.prefix}/motor/gui/*",
    f"{KEYS.prefix}/motor/*/stop",
    f"{KEYS.prefix}/motor/gui/st$*",
    "**",
)
TARGETS = (zenoh.QueryTarget.BEST_MATCHING, zenoh.QueryTarget.ALL, zenoh.QueryTarget.ALL_COMPLETE)


def _motor_status(session: zenoh.Session) -> dict:
    ok, status = call(session, KEYS.status(Service.MOTOR))
    assert ok, status
    return status


def _control_state(status: dict) -> dict:
    return {name: status[name] for name in ("state", "gains", "target")} | {"bad_input": status["bad_input"]["total"]}


@pytest.fixture(scope="module")
def running_loop() -> Iterator[str]:
    """Router, motor, a realtime sim and a constant-velocity drive, each its own process."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    connect = ("--connect", endpoint)
    with (
        InventProcess("router", "--listen", endpoint) as router,
        InventProcess("motor", *connect, *ROBOT_FLAGS) as motor,
        InventProcess("sim", *connect, *ROBOT_FLAGS, "--mode", "realtime") as sim,
        InventProcess(
            "drive", *connect, *ROBOT_FLAGS, "--for", "3600", "--vx", str(TARGET["vx"]), "--w", str(TARGET["w"])
        ) as drive,
    ):
        yield endpoint
        for process in (drive, sim, motor, router):
            process.stop()


@pytest.fixture
def loop_session(running_loop: str) -> Iterator[zenoh.Session]:
    with peer_session(running_loop) as session:
        for service in (Service.MOTOR, Service.SIM, Service.DRIVE):
            wait_alive(session, KEYS.alive(service))
        wait_until(lambda: _motor_status(session)["state"] == "running", 20, "the motor to run")
        wait_until(lambda: _motor_status(session)["target"] == TARGET, 20, "the drive's target")
        yield session


def test_wildcard_gets_reach_no_motor_method_and_change_nothing(loop_session):
    before = _control_state(_motor_status(loop_session))
    answered_by_status = set()
    for key_expr in WILDCARDS:
        for target in TARGETS:
            for payload in (None, ABSURD_GAINS):
                replies = list(loop_session.get(key_expr, target=target, payload=payload, timeout=1.0))
                keys = {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}
                errors = [reply.err.payload.to_string() for reply in replies if reply.err is not None]
                assert not keys & METHOD_KEYS, (key_expr, target, keys)
                assert not errors, (key_expr, target, errors)
                answered_by_status |= keys
    assert _control_state(_motor_status(loop_session)) == before
    # Reading still works through the same wildcards: the status queryables answer them.
    assert {KEYS.status(Service.MOTOR), KEYS.status(Service.SIM), KEYS.status(Service.DRIVE)} <= answered_by_status


def test_exact_method_calls_still_act(loop_session):
    gains = {"p_gain_l": 4.0, "p_gain_r": 4.5, "d_gain_l": 1.5, "d_gain_r": 1.75}
    ok, status = call(loop_session, KEYS.method(MethodFamily.GUI, Method.SET_PD_GAIN), json.dumps(gains))
    assert ok and status["gains"] == gains
    ok, status = call(loop_session, KEYS.method(MethodFamily.GUI, Method.STOP))
    assert ok and status["state"] == "stopped"
    ok, status = call(loop_session, KEYS.method(MethodFamily.BUMP, Method.CLEAR))
    assert ok and status["state"] == "running"
    ok, status = call(
        loop_session,
        KEYS.method(MethodFamily.GUI, Method.SET_PD_GAIN),
        json.dumps({"p_gain_l": 5.0, "p_gain_r": 5.0, "d_gain_l": 2.0, "d_gain_r": 2.0}),
    )
    assert ok and status["state"] == "running"


def _listening_addresses(pid: int) -> set[str]:
    """host:port of every TCP socket in LISTEN state, and every bound UDP socket, that ``pid`` holds."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:[") : -1])
    addresses = set()
    for table, listening_state in (("tcp", "0A"), ("tcp6", "0A"), ("udp", "07"), ("udp6", "07")):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            if inode in inodes and state == listening_state:
                addresses.add(_decode_address(local))
    return addresses


def _decode_address(hex_address: str) -> str:
    host, port = hex_address.split(":")
    raw = bytes.fromhex(host)
    # /proc stores the address as native-endian 32-bit words.
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return f"{ipaddress.ip_address(words)}:{int(port, 16)}"


@pytest.mark.parametrize(
    "command",
    [("motor", *ROBOT_FLAGS), ("echo", f"{KEYS.prefix}/**")],
    ids=["service", "tool"],
)
def test_a_process_started_without_listen_listens_on_loopback_only(endpoint, session, command):
    with InventProcess(*command, "--connect", endpoint) as process:
        if command[0] == "motor":
            wait_alive(session, KEYS.alive(Service.MOTOR))
        addresses = wait_until(lambda: _listening_addresses(process.process.pid), 20, "a listening socket")
        assert all(ipaddress.ip_address(address.rsplit(":", 1)[0]).is_loopback for address in addresses), addresses
        process.stop()


def test_listen_opens_more_beside_loopback(endpoint, session):
    with InventProcess("motor", *ROBOT_FLAGS, "--connect", endpoint, "--listen", "tcp/0.0.0.0:0") as process:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        addresses = wait_until(
            lambda: (found := _listening_addresses(process.process.pid)) and len(found) == 2 and found,
            20,
            "two listening sockets",
        )
        hosts = {address.rsplit(":", 1)[0] for address in addresses}
        assert hosts == {"127.0.0.1", "0.0.0.0"}, addresses
        process.stop()
