"""The secure profile's router with real sessions (TCP and TLS): it lets each role do only what it is
granted, for the services, the operator, the ROS 2 bridge and `invent goto`; and `invent up --secure`
with the real services (tests/test_security.py: the roles, their grants and the files `invent secrets` writes).
"""

from __future__ import annotations

import json
import math
import queue
import stat
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from functools import partial
from pathlib import Path

import msgspec
import pytest
import zenoh
import zenoh.ext

from schemas.codec import encode
from schemas.keys import LOOP_SERVICES, Keys, Service
from schemas.messages import ScenarioOutcome, Time, TimedPosition, TimedVelocity
from schemas.navigation import GoalReply, GoalRequest
from schemas.topics import Method, MethodFamily, Topic
from services import interfaces
from services.config import Config
from services.exits import ExitStatus
from services.ros2.graph import PUBLICATIONS
from services.security import (
    DEFAULT_ROS,
    Profile,
    Role,
    write_profile,
)
from tests.goal_standin import GOAL_REFUSED, StandInDrive
from tests.harness import InventProcess, call, free_port, noting_replier, run_invent, start_up, wait_until
from tests.test_security import FORGED_VX, GOALS, KEYS


@contextmanager
def _secured_router(tmp_path: Path, tls: bool) -> Iterator[tuple[Profile, Callable[[Role], zenoh.Session]]]:
    """A router from a fresh profile, and a function that opens a client session as a role."""
    host = "localhost" if tls else "127.0.0.1"
    profile = write_profile(tmp_path / "secrets", KEYS, endpoint=f"tcp/{host}:{free_port()}", tls=tls)
    with ExitStack() as stack:
        stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.router_config))))

        def open_as(role: Role) -> zenoh.Session:
            return stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.client_config(role)))))

        yield profile, open_as


def _witnessing(witness: zenoh.Session) -> queue.Queue[tuple[str, str]]:
    """What ``witness`` (an observer, who reads every key) receives: (key, payload); it answers invent
    view's status, the barrier of the tools' sessions (:func:`_all_put`)."""
    received: queue.Queue[tuple[str, str]] = queue.Queue()
    witness.declare_subscriber(
        KEYS.everything, lambda sample: received.put((str(sample.key_expr), sample.payload.to_string()))
    )
    witness.declare_queryable(KEYS.view_status, lambda query: query.reply(KEYS.view_status, b"{}"))
    return received


def _all_put(role: Role, session: zenoh.Session, witness: zenoh.Session) -> None:
    """Return once everything ``session`` (logged in as ``role``) put has reached ``witness``: a
    query and its reply cross the router after what their sender put before them (one transport
    each way, in order). A tool's session asks the witness's status; a service may query none, so
    the witness asks the service's own status, which the session now serves."""
    if role in (Role.OPERATOR, Role.OBSERVER, Role.ROS_NODE):
        assert len([reply.ok for reply in session.get(KEYS.view_status, timeout=5.0) if reply.ok]) == 1, role
        return
    own = KEYS.control_status if role is Role.CONTROL else KEYS.status(Service(role.value))
    session.declare_queryable(own, lambda query: query.reply(own, b"{}"))
    wait_until(lambda: [reply for reply in witness.get(own, timeout=1.0) if reply.ok], 10, f"{role}'s status")


def _declared_puts(service: Service) -> set[str]:
    return set(interfaces.declared(service, KEYS, Config()).publishes)


def _client_config(endpoint: str, user: str | None = None, password: str | None = None) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("connect/timeout_ms", "1500")
    if user is not None:
        config.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        config.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return config


@pytest.mark.parametrize("tls", [False, True], ids=["tcp", "tls"])
def test_router_delivers_each_roles_puts_only_on_the_keys_its_interface_declares_and_refuses_strangers(tmp_path, tls):
    with _secured_router(tmp_path, tls) as (profile, open_as):
        witness = open_as(Role.OBSERVER)
        received = _witnessing(witness)
        sessions = {role: open_as(role) for role in Role}
        # BLOCK, not zenoh's default DROP: hundreds of puts at once on a link just opened, on a loaded
        # machine, must not be dropped in transport (a flake once delivered none of them)
        publishers = [
            (role, session.declare_publisher(KEYS.topic(topic), congestion_control=zenoh.CongestionControl.BLOCK))
            for role, session in sessions.items()
            for topic in Topic
        ]
        wait_until(lambda: all(p.matching_status.matching for _, p in publishers), 10, "the witness to match")
        for role, publisher in publishers:
            publisher.put(f"{role}")
        for role, session in sessions.items():
            _all_put(role, session, witness)
        delivered = set()
        while not received.empty():
            delivered.add(received.get())
        # what each service declares it publishes (services/interfaces.py), and nothing else
        declared = {Role(service.value): _declared_puts(service) for service in LOOP_SERVICES}
        declared[Role.CONTROL] = declared[Role.SIM] | declared[Role.MOTOR]
        declared[Role.ROS2] = {KEYS.drive_target_velocity}
        declared[Role.OPERATOR] = {KEYS.drive_target_velocity, KEYS.run_summary}
        assert delivered == {(key, str(role)) for role, keys in declared.items() for key in keys}

        stranger_endpoint = profile.endpoint
        for user, password in ((None, None), (str(Role.OPERATOR), "not-the-password")):
            with pytest.raises(zenoh.ZError):
                zenoh.open(_client_config(stranger_endpoint, user, password))
        if tls:
            plain = stranger_endpoint.replace("tls/", "tcp/")
            with pytest.raises(zenoh.ZError):
                zenoh.open(_client_config(plain, str(Role.OBSERVER), "x"))


SERVICE_ROLES = (Role.SIM, Role.MOTOR, Role.ODOMETRY, Role.LOCALIZATION, Role.DRIVE, Role.ROS2, Role.CONTROL)


@pytest.mark.parametrize("role", SERVICE_ROLES, ids=str)
def test_a_services_role_puts_what_its_service_declares_and_the_router_refuses_every_other_data_key(tmp_path, role):
    """One service kind through a real router: its credentials put on every data key of the robot;
    a reader gets exactly the keys its service declares (services/interfaces.py), nothing else."""
    declared = {Role(service.value): _declared_puts(service) for service in LOOP_SERVICES}
    declared[Role.CONTROL] = declared[Role.SIM] | declared[Role.MOTOR]
    declared[Role.ROS2] = set(interfaces.declared(Service.ROS2, KEYS, Config()).publishes)
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        witness = open_as(Role.OBSERVER)
        received = _witnessing(witness)
        session = open_as(role)
        publishers = [
            session.declare_publisher(KEYS.topic(topic), congestion_control=zenoh.CongestionControl.BLOCK)
            for topic in Topic
        ]
        wait_until(lambda: all(p.matching_status.matching for p in publishers), 10, "the witness to match")
        for publisher in publishers:
            publisher.put(str(role))
        _all_put(role, session, witness)
        delivered = set()
        while not received.empty():
            delivered.add(received.get())
    assert delivered == {(key, str(role)) for key in declared[role]}
    assert len(declared[role]) < len(Topic), "some keys are not its own: the router refused those"


def test_router_routes_method_queries_only_from_the_operator_and_bump_stop_only_from_the_sim_and_control(tmp_path):
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        motor = open_as(Role.MOTOR)
        calls: list[str] = []

        def serve(query: zenoh.Query) -> None:
            calls.append(str(query.key_expr))
            query.reply(query.key_expr, b"{}")

        for family in MethodFamily:
            for method in Method:
                motor.declare_queryable(KEYS.method(family, method), serve)
        motor.declare_queryable(KEYS.status(Service.MOTOR), lambda q: q.reply(KEYS.status(Service.MOTOR), b"{}"))
        operator, sim, observer = open_as(Role.OPERATOR), open_as(Role.SIM), open_as(Role.OBSERVER)
        wait_until(lambda: list(observer.get(KEYS.status(Service.MOTOR), timeout=1.0)), 10, "the motor's status")
        expected = []
        callers = {Role.OPERATOR: operator, Role.SIM: sim, Role.CONTROL: open_as(Role.CONTROL), Role.OBSERVER: observer}
        bump = ((Role.SIM, MethodFamily.BUMP), (Role.CONTROL, MethodFamily.BUMP))
        for role, session in callers.items():
            for family in MethodFamily:
                key = KEYS.method(family, Method.STOP)
                replies = [reply for reply in session.get(key, timeout=1.0) if reply.ok is not None]
                allowed = (role, family) in ((Role.OPERATOR, MethodFamily.GUI), *bump)
                assert len(replies) == int(allowed), (role, family)
                expected += [key] if allowed else []
        assert calls == expected


def test_router_lets_the_control_path_put_and_serve_what_the_sim_and_the_motor_may_and_nothing_else(tmp_path):
    """Real sessions through a secured router: one session logged in as ``control`` (``invent
    control``: the sim and the motor on one session) puts ``motor/torque`` and ``sim/wheel_angles``
    and serves ``motor/gui/stop`` to the operator; its put on ``drive/target_velocity`` (neither the
    sim's nor the motor's) reaches no subscriber."""
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        witness = open_as(Role.OBSERVER)
        received = _witnessing(witness)
        control = open_as(Role.CONTROL)
        keys = (KEYS.drive_target_velocity, KEYS.motor_torque, KEYS.sim_wheel_angles)  # the forbidden one first
        publishers = [control.declare_publisher(key) for key in keys]
        wait_until(lambda: all(p.matching_status.matching for p in publishers), 10, "the witness to match")
        for publisher in publishers:
            publisher.put("control")
        _all_put(Role.CONTROL, control, witness)
        delivered = set()
        while not received.empty():
            delivered.add(received.get())
        assert delivered == {(KEYS.motor_torque, "control"), (KEYS.sim_wheel_angles, "control")}

        calls: list[tuple[str, str]] = []
        stop = KEYS.method(MethodFamily.GUI, Method.STOP)
        control.declare_queryable(stop, noting_replier(calls, "control"))
        operator = open_as(Role.OPERATOR)
        wait_until(lambda: [r for r in operator.get(stop, timeout=1.0) if r.ok is not None], 10, "control's stop")
    assert calls and set(calls) == {("control", stop)}, "the operator's stop reached the control session"


def test_router_routes_goals_only_from_the_operator_and_the_bridge_and_only_to_the_drive(tmp_path):
    """Real sessions through a secured router: a drive-role session serves drive/goal/send and
    cancel; the operator's and the ROS 2 bridge's queries reach it, the observer's and every other
    role's do not; another role declaring the same queryables (an impostor drive) is never routed to."""
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        calls: list[tuple[str, str]] = []
        serve = partial(noting_replier, calls, reply=GOAL_REFUSED)

        drive, impostor = open_as(Role.DRIVE), open_as(Role.OPERATOR)
        for key in sorted(GOALS):
            impostor.declare_queryable(key, serve("impostor"))
            drive.declare_queryable(key, serve("drive"))
        status = KEYS.status(Service.DRIVE)
        drive.declare_queryable(status, lambda query: query.reply(status, b"{}"))
        sessions = {role: open_as(role) for role in Role if role is not Role.DRIVE}
        # Once the drive's status answers an observer, its declarations before it reached the router.
        wait_until(lambda: call(sessions[Role.OBSERVER], status)[0], 10, "the drive's status")
        answered = {
            role: sorted(key for key in GOALS for reply in session.get(key, timeout=1.0) if reply.ok is not None)
            for role, session in sessions.items()
        }
    assert answered == {role: sorted(GOALS) if role in (Role.OPERATOR, Role.ROS2) else [] for role in sessions}
    assert sorted(calls) == sorted(("drive", key) for key in GOALS for _role in (Role.OPERATOR, Role.ROS2))


def test_invent_goto_as_the_observer_reaches_no_drive_and_as_the_operator_drives_to_the_outcome(tmp_path):
    """``invent goto`` with a role's file through a secured router, a stand-in drive with the drive's
    credentials: the observer's goal is never routed to it (exit 1 naming the key); the operator's
    is accepted, and its outcome is goto's exit status."""
    with _secured_router(tmp_path, tls=False) as (profile, open_as):
        drive = StandInDrive(open_as(Role.DRIVE), KEYS, lambda _request: GoalReply(True, "g1"))
        goal = ("goto", "1.5", "0.5", "1.57", "--robot", KEYS.robot, "--wait", "2", "--zenoh-config")
        refused = run_invent(*goal, str(profile.client_config(Role.OBSERVER)))
        assert refused.returncode == ExitStatus.FAILURE, refused.stderr
        assert f"no reply from {KEYS.drive_goal_send}" in refused.stderr and "only the operator" in refused.stderr
        assert drive.goals.empty(), "the observer's goal never reached the drive"
        with InventProcess(*goal, str(profile.client_config(Role.OPERATOR))) as operator:
            assert drive.goals.get(timeout=20) == GoalRequest(x=1.5, y=0.5, theta=1.57)
            drive.wait_for_subscribers()
            drive.publish(KEYS.drive_outcome, ScenarioOutcome(Time(4, 0), "goals", "completed", "", 0, 3.5, "g1"))
            out, err = operator.process.communicate(timeout=20)
        drive.close()
    assert operator.process.returncode == ExitStatus.OK, err
    assert out.splitlines()[-1] == "outcome: completed (goal g1 after 3.50 s)"


def test_up_secure_refuses_flags_that_would_bypass_the_router(tmp_path):
    for flags, named in ((["--composed"], "--composed"), (["--connect", "tcp/127.0.0.1:1"], "--connect")):
        result = run_invent("up", "--secure", "--report", str(tmp_path), *flags)
        assert result.returncode == 2 and named in result.stderr, result.stderr
    result = run_invent("up", "--tls", "--report", str(tmp_path))
    assert result.returncode == 2 and "--secure" in result.stderr


@pytest.mark.slow
def test_up_secure_runs_the_square_and_enforces_every_role(tmp_path):
    report_dir = tmp_path / "report"
    secrets = report_dir / "secrets"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys()
    process = start_up("--secure", "--ros2", "--scenario", "square", "--report", str(report_dir), "--listen", endpoint)
    output: list[str] = []

    def drive_started() -> bool:
        line = process.stdout.readline()
        output.append(line)
        return "started drive" in line or not line

    try:
        wait_until(drive_started, 120, "invent up --secure to start the drive")
        assert process.poll() is None, "".join(output)

        def open_as(role: Role) -> zenoh.Session:
            return zenoh.open(zenoh.Config.from_file(str(secrets / f"{role}.json5")))

        with open_as(Role.OBSERVER) as observer, open_as(Role.OBSERVER) as witness, open_as(Role.OPERATOR) as operator:
            poses: queue.Queue[bytes] = queue.Queue()
            observer.declare_subscriber(keys.odometry_pose, lambda sample: poses.put(sample.payload.to_bytes()))
            msgspec.json.decode(poses.get(timeout=20.0), type=TimedPosition)
            wait_until(lambda: call(observer, keys.status(Service.MOTOR))[1]["state"] == "running", 20, "the motor")

            targets: queue.Queue[float] = queue.Queue()
            witness.declare_subscriber(
                keys.drive_target_velocity,
                lambda sample: targets.put(msgspec.json.decode(sample.payload.to_bytes(), type=TimedVelocity).vx),
            )
            targets.get(timeout=20.0)  # the drive's targets reach the witness
            forged = TimedVelocity(tm=Time(0, 0), id=[], vx=FORGED_VX, vy=0.0, w=0.0, error=[])
            for _ in range(20):
                observer.put(keys.drive_target_velocity, encode(forged))
            stop = keys.method(MethodFamily.GUI, Method.STOP)
            assert [reply for reply in observer.get(stop, timeout=1.0)] == []
            seen = [targets.get(timeout=5.0) for _ in range(20)]  # the drive's, published after the forgeries
            assert FORGED_VX not in seen
            ok, status = call(observer, keys.status(Service.MOTOR))
            assert ok and status["state"] == "running" and status["target"]["vx"] != FORGED_VX

            for user, password in ((None, None), (str(Role.OPERATOR), "not-the-password")):
                with pytest.raises(zenoh.ZError):
                    zenoh.open(_client_config(endpoint, user, password))

            with open_as(Role.ROS_NODE) as ros_node:
                odom_key = DEFAULT_ROS.key(PUBLICATIONS["odom"])
                odometry: queue.Queue[bytes | None] = queue.Queue()
                ros_node.declare_subscriber(
                    odom_key, lambda s: odometry.put(s.attachment.to_bytes() if s.attachment else None)
                )
                attachment = odometry.get(timeout=20.0)
                assert attachment is not None and len(attachment) == 33, "the bridge's /odom through the router"

            ok, status = call(operator, stop)
            assert ok and status["state"] == "stopped"
            ok, status = call(operator, keys.method(MethodFamily.GUI, Method.CLEAR))
            assert ok and status["state"] != "stopped"
        rest, _ = process.communicate(timeout=180)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    output.append(rest)
    assert process.returncode == 0, "".join(output)[-4000:]
    report = json.loads((report_dir / "report.json").read_text())
    start, end = report["start"], report["final"]["ground_truth"]
    assert math.hypot(end["x"] - start["x"], end["y"] - start["y"]) < 0.05
    assert report["path_error"]["max_m"] < 0.10
    assert report["odometry_error"]["max_m"] < 0.05
    assert report["bad_inputs"] == {"motor": 0, "odometry": 0, "sim": 0, "localization": 0, "drive": 0, "ros2": 0}
    assert all(stat.S_IMODE(path.stat().st_mode) == 0o600 for path in secrets.iterdir())
