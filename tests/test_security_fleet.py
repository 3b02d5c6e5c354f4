"""Per-robot credentials (issue 26): a fleet's profile, its users and grants per robot, and the
router's access control with real sessions: one robot's credentials cannot put on, call or serve
the methods of another robot; the fleet's sim and operator reach every robot."""

from __future__ import annotations

import argparse
import dataclasses
import json
import queue
import stat
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from functools import partial
from pathlib import Path

import pytest
import zenoh

from schemas.keys import Keys, Service, all_robots_status
from schemas.topics import LATCHED_TOPICS, LocalizationMethod, Method, MethodFamily, Topic
from services.cli.flags import robot_names
from services.cli.tools import run_secrets
from services.ros2.graph import MOTOR_SERVICES, PUBLICATIONS, BridgeGraph
from services.security import (
    DEFAULT_ROS,
    DICTIONARY,
    FLEET_ROLES,
    PER_ROBOT_ROLES,
    ROUTER_CONFIG,
    Flow,
    Identity,
    Message,
    Profile,
    Role,
    fleet_grants,
    fleet_identities,
    fleet_robots,
    grants,
    robot_bridge,
    write_fleet_profile,
    write_profile,
)
from tests.goal_standin import GOAL_REFUSED
from tests.harness import free_port, noting_replier, run_invent, wait_until

ROBOTS = ("rh0", "rh1")
RH0, RH1 = Keys("rh0"), Keys("rh1")
BRIDGES = {robot: robot_bridge(DEFAULT_ROS, robot, publishes_clock=robot == ROBOTS[0]) for robot in ROBOTS}
"""As write_fleet_profile grants them by default: each robot in its namespace, /clock the first robot's."""


def _granted(identity: Identity, message: Message, flow: Flow = Flow.INGRESS) -> set[str]:
    """The key expressions on which ``identity`` may send ``message`` in the fleet ``ROBOTS``."""
    return {
        key
        for grant in fleet_grants(identity, ROBOTS, BRIDGES)
        if message in grant.messages and grant.flow is flow
        for key in grant.key_exprs
    }


def _single(role: Role, keys: Keys, message: Message, flow: Flow = Flow.INGRESS) -> set[str]:
    """The same, for ``role`` in a single robot's profile for ``keys.robot``."""
    return {
        key
        for grant in grants(role, keys, BRIDGES[keys.robot])
        if message in grant.messages and grant.flow is flow
        for key in grant.key_exprs
    }


def _methods(keys: Keys, family: MethodFamily) -> set[str]:
    return {keys.method(family, method) for method in Method}


def _goals(keys: Keys) -> set[str]:
    """The drive's goal queryables of ``keys.robot``."""
    return {keys.drive_goal_send, keys.drive_goal_cancel}


def test_each_robots_service_roles_get_exactly_the_single_robot_grants_on_their_robot_only():
    for robot in ROBOTS:
        other = Keys(next(r for r in ROBOTS if r != robot))
        for role in PER_ROBOT_ROLES:
            identity = Identity(role, robot)
            assert fleet_grants(identity, ROBOTS, BRIDGES) == grants(role, Keys(robot), BRIDGES[robot]), identity
            for message in (Message.PUT, Message.DECLARE_QUERYABLE, Message.LIVELINESS_TOKEN, Message.QUERY):
                named = _granted(identity, message)
                assert not any(key.startswith(f"{other.prefix}/") for key in named), (identity, message)
    assert _granted(Identity(Role.MOTOR, "rh1"), Message.PUT) == {
        RH1.motor_torque,
        RH1.motor_wheel_velocity,
        RH1.motor_wheel_angles,
        RH1.motor_sim_pose_gui,
        RH1.motor_sim_pose_localization,
        RH1.motor_state,
    }
    assert _granted(Identity(Role.MOTOR, "rh1"), Message.DECLARE_QUERYABLE) == (
        {RH1.status(Service.MOTOR), RH1.motor_state}
        | _methods(RH1, MethodFamily.GUI)
        | _methods(RH1, MethodFamily.BUMP)
    )
    ros2_calls = _granted(Identity(Role.ROS2, "rh1"), Message.QUERY) - {all_robots_status()}
    assert ros2_calls - {RH1.topic(topic) for topic in LATCHED_TOPICS} == {
        RH1.method(MethodFamily.GUI, method) for method in MOTOR_SERVICES
    } | _goals(RH1) | {RH1.localization_initial_pose}
    assert _granted(Identity(Role.DRIVE, "rh1"), Message.DECLARE_QUERYABLE) == (
        {RH1.status(Service.DRIVE), RH1.drive_path, RH1.drive_outcome, RH1.drive_goal, RH1.drive_map, RH1.drive_plan}
        | _goals(RH1)
    )


def test_each_robots_bridge_is_granted_its_own_ros_namespace_and_not_the_others():
    odom = {robot: BRIDGES[robot].key(PUBLICATIONS["odom"]) for robot in ROBOTS}
    assert odom["rh1"].startswith("0/rh1/odom/") and odom["rh0"].startswith("0/rh0/odom/")
    assert odom["rh1"] in _granted(Identity(Role.ROS2, "rh1"), Message.PUT)
    assert odom["rh0"] not in _granted(Identity(Role.ROS2, "rh1"), Message.PUT)
    stop = {robot: BRIDGES[robot].key(MOTOR_SERVICES[Method.STOP]) for robot in ROBOTS}
    assert stop["rh1"] in _granted(Identity(Role.ROS2, "rh1"), Message.DECLARE_QUERYABLE)
    assert stop["rh0"] not in _granted(Identity(Role.ROS2, "rh1"), Message.DECLARE_QUERYABLE)
    assert _granted(Identity(Role.ROS_NODE), Message.PUT) == {"0/**", "0/**/@adv/**", "@ros2_lv/0/**"}


def test_each_robots_bridge_is_granted_its_own_navigate_to_pose_action_and_goal_pose_and_not_the_others():
    from services.ros2.graph import ACTION_SERVICES, ACTION_TOPICS, GOAL_POSE

    for robot, other in (("rh0", "rh1"), ("rh1", "rh0")):
        bridge = Identity(Role.ROS2, robot)
        served, puts = _granted(bridge, Message.DECLARE_QUERYABLE), _granted(bridge, Message.PUT)
        subscribed = _granted(bridge, Message.DECLARE_SUBSCRIBER)
        for name, entity in ACTION_SERVICES.items():
            assert BRIDGES[robot].key(entity).startswith(f"0/{robot}/navigate_to_pose/_action/{name}/")
            assert BRIDGES[robot].key(entity) in served and BRIDGES[other].key(entity) not in served
        for entity in ACTION_TOPICS.values():
            assert BRIDGES[robot].key(entity) in puts and BRIDGES[other].key(entity) not in puts
        assert BRIDGES[robot].key(GOAL_POSE) in subscribed and BRIDGES[other].key(GOAL_POSE) not in subscribed


def test_each_robots_bridge_is_granted_its_namespaces_tf_and_only_the_first_robots_bridge_clock():
    tf = {robot: BRIDGES[robot].key(BRIDGES[robot].publications["tf"]) for robot in ROBOTS}
    assert tf["rh0"].startswith("0/rh0/tf/") and tf["rh1"].startswith("0/rh1/tf/")
    clock = DEFAULT_ROS.key(PUBLICATIONS["clock"])
    puts = {robot: _granted(Identity(Role.ROS2, robot), Message.PUT) for robot in ROBOTS}
    assert tf["rh0"] in puts["rh0"] and tf["rh0"] not in puts["rh1"] and tf["rh1"] in puts["rh1"]
    assert clock in puts["rh0"] and clock not in puts["rh1"], "/clock, one for the world: the first robot's bridge"
    shared = {robot: dataclasses.replace(BRIDGES[robot], tf_shared=True) for robot in ROBOTS}
    shared_tf = DEFAULT_ROS.key(dataclasses.replace(PUBLICATIONS["tf"], name="/tf"))
    assert all(shared_tf in _granted_in(Identity(Role.ROS2, robot), shared, Message.PUT) for robot in ROBOTS), (
        "with frame prefixes every bridge publishes on the shared /tf"
    )


def test_the_fleet_sim_puts_serves_and_calls_the_sim_keys_and_bump_methods_of_every_robot():
    sim = Identity(Role.SIM)
    for keys in (RH0, RH1):
        for message in Message:
            for flow in Flow:
                assert _single(Role.SIM, keys, message, flow) <= _granted(sim, message, flow), (keys, message, flow)
    assert _granted(sim, Message.PUT) == {keys.topic(t) for keys in (RH0, RH1) for t in Topic if t.startswith("sim/")}
    assert _granted(sim, Message.QUERY) == (
        {all_robots_status()}
        | {keys.topic(topic) for keys in (RH0, RH1) for topic in LATCHED_TOPICS}
        | _methods(RH0, MethodFamily.BUMP)
        | _methods(RH1, MethodFamily.BUMP)
    )
    assert not _granted(sim, Message.QUERY) & (_methods(RH0, MethodFamily.GUI) | _methods(RH1, MethodFamily.GUI))
    assert _granted(sim, Message.LIVELINESS_TOKEN) == {
        token for keys in (RH0, RH1) for token in (keys.alive(Service.SIM), keys.ticks_at_any_rate(Service.SIM))
    }


def test_the_fleet_operator_and_observer_reach_every_robot_and_the_observer_puts_nothing():
    operator, observer = Identity(Role.OPERATOR), Identity(Role.OBSERVER)
    assert _granted(operator, Message.PUT) == {k.drive_target_velocity for k in (RH0, RH1)} | {
        k.run_summary for k in (RH0, RH1)
    }
    assert _granted(operator, Message.QUERY) - {all_robots_status()} - {
        keys.topic(topic) for keys in (RH0, RH1) for topic in LATCHED_TOPICS
    } == (
        _methods(RH0, MethodFamily.GUI)
        | _methods(RH1, MethodFamily.GUI)
        | _goals(RH0)
        | _goals(RH1)
        | {k.localization_method(m) for k in (RH0, RH1) for m in LocalizationMethod}
        | {k.odometry_set_pose for k in (RH0, RH1)}
    )
    assert _granted(observer, Message.PUT) == set()
    assert not _granted(observer, Message.QUERY) & (_goals(RH0) | _goals(RH1)), "the observer sends no goal"
    assert _granted(observer, Message.DECLARE_QUERYABLE) == {RH0.view_status, RH1.view_status}


def test_a_fleet_names_each_robot_once_with_valid_names():
    assert fleet_robots(["rh0", "rh1"]) == ROBOTS
    for bad, named in ((["rh0", "rh/1"], "rh/1"), (["rh0", "rh0"], "rh0"), (["r*"], "r*"), ([], "at least one")):
        with pytest.raises(ValueError, match=named.replace("*", r"\*")):
            fleet_robots(bad)
    with pytest.raises(ValueError, match="not in the fleet"):
        fleet_grants(Identity(Role.MOTOR, "rh2"), ROBOTS, BRIDGES)
    with pytest.raises(ValueError, match="fleet-wide"):
        fleet_grants(Identity(Role.SIM, "rh0"), ROBOTS, BRIDGES)
    with pytest.raises(ValueError, match="per robot"):
        fleet_grants(Identity(Role.MOTOR), ROBOTS, BRIDGES)


def test_a_fleet_has_no_control_role_it_is_one_robots(tmp_path):
    """``invent control`` (the sim and the motor on one session) is one robot's: a fleet's sim steps
    every robot while each robot has its own motor. A single robot's profile has ``control.json5``."""
    assert Role.CONTROL not in FLEET_ROLES and Role.CONTROL not in PER_ROBOT_ROLES
    assert all(identity.role is not Role.CONTROL for identity in fleet_identities(ROBOTS))
    for robot in (None, "rh1"):
        with pytest.raises(ValueError, match="a fleet has no control role"):
            fleet_grants(Identity(Role.CONTROL, robot), ROBOTS, BRIDGES)
    profile = write_fleet_profile(tmp_path / "secrets", ROBOTS, endpoint="tcp/127.0.0.1:7447")
    for robot in (None, "rh1"):
        with pytest.raises(ValueError, match=r"a fleet has no control role \(it is one robot's\)"):
            profile.identity(Role.CONTROL, robot)
        with pytest.raises(ValueError, match="a fleet has no control role"):
            profile.client_config(Role.CONTROL, robot)
    assert not any("control" in path.name for path in profile.directory.iterdir())
    single = write_profile(tmp_path / "one", RH0, endpoint="tcp/127.0.0.1:7447")
    assert single.client_config(Role.CONTROL) == single.directory / "control.json5"
    assert single.client_config(Role.CONTROL).is_file() and Identity(Role.CONTROL) in single.identities


def test_a_fleet_profile_has_one_private_user_and_client_file_per_robot_and_service_role(tmp_path):
    profile = write_fleet_profile(tmp_path / "secrets", ROBOTS, endpoint="tcp/127.0.0.1:7447")
    assert profile.robots == ROBOTS
    identities = fleet_identities(ROBOTS)
    users = [identity.user for identity in identities]
    assert users == [*(str(role) for role in FLEET_ROLES), *(f"{r}-{role}" for r in ROBOTS for role in PER_ROBOT_ROLES)]
    assert len(set(users)) == len(users) and set(profile.identities) == set(identities)
    files = list(profile.directory.iterdir())
    assert {path.name for path in files} == {ROUTER_CONFIG, DICTIONARY} | {f"{user}.json5" for user in users}
    assert all(stat.S_IMODE(path.stat().st_mode) == 0o600 for path in files)
    passwords = dict(line.split(":") for line in (profile.directory / DICTIONARY).read_text().splitlines())
    assert list(passwords) == users and len(set(passwords.values())) == len(users)
    for identity in identities:
        path = profile.client_config(identity.role, identity.robot)
        config = json.loads(str(zenoh.Config.from_file(str(path))))
        assert config["mode"] == "client" and config["connect"]["endpoints"] == ["tcp/127.0.0.1:7447"]
        login = config["transport"]["auth"]["usrpwd"]
        assert (login["user"], login["password"]) == (identity.user, passwords[identity.user])
    assert profile.client_config(Role.MOTOR, "rh1") == profile.directory / "rh1-motor.json5"
    assert profile.client_config(Role.SIM, "rh1") == profile.client_config(Role.SIM) == profile.directory / "sim.json5"
    for role, robot, named in ((Role.MOTOR, None, "per robot"), (Role.MOTOR, "rh2", "rh2"), (Role.SIM, "rh2", "rh2")):
        with pytest.raises(ValueError, match=named):
            profile.client_config(role, robot)
    router = json.loads(str(zenoh.Config.from_file(str(profile.router_config))))["access_control"]
    assert router["default_permission"] == "deny"
    assert {subject["usernames"][0] for subject in router["subjects"]} == set(users)
    single = write_profile(tmp_path / "one", RH0, endpoint="tcp/127.0.0.1:7447")
    assert single.robots == () and single.client_config(Role.MOTOR) == single.directory / "motor.json5"
    with pytest.raises(ValueError, match="single robot"):
        single.client_config(Role.MOTOR, "rh0")


def test_robot_names_that_look_like_paths_or_the_tls_directory_stay_plain_files_in_the_profile(tmp_path):
    profile = write_fleet_profile(tmp_path / "secrets", ["tls", "..", "."], endpoint="tcp/127.0.0.1:7447", tls=True)
    assert {path.parent for path in profile.directory.rglob("*.json5")} == {profile.directory}
    assert (profile.directory / "..-motor.json5").is_file() and (profile.directory / "tls" / "ca.pem").is_file()
    assert {path.name for path in tmp_path.iterdir()} == {"secrets"}


def test_explicit_bridges_replace_the_default_namespaces():
    bridges = {"rh0": BridgeGraph(3, "/fleet/a", "bridge_a"), "rh1": BridgeGraph(4, "", "bridge_b")}
    node = _granted_in(Identity(Role.ROS_NODE), bridges, Message.PUT)
    assert node == {"3/**", "3/**/@adv/**", "@ros2_lv/3/**", "4/**", "4/**/@adv/**", "@ros2_lv/4/**"}
    rh0_bridge = _granted_in(Identity(Role.ROS2, "rh0"), bridges, Message.PUT)
    assert bridges["rh0"].key(PUBLICATIONS["odom"]) in rh0_bridge and not any(k.startswith("4/") for k in rh0_bridge)


def _granted_in(identity: Identity, bridges: dict[str, BridgeGraph], message: Message) -> set[str]:
    return {
        key
        for grant in fleet_grants(identity, ROBOTS, bridges)
        if message in grant.messages and grant.flow is Flow.INGRESS
        for key in grant.key_exprs
    }


def test_robots_flag_type_takes_comma_separated_names_and_a_bad_one_is_a_usage_error_naming_the_flag(capsys):
    assert robot_names("rh0,rh1") == ROBOTS and robot_names(" rh0 , rh1 ") == ROBOTS
    parser = argparse.ArgumentParser(prog="invent secrets")
    parser.add_argument("--robots", type=robot_names)
    for bad in ("rh0,rh 1", "rh0,,rh1", "rh0,rh0", "rh/0"):
        with pytest.raises(SystemExit) as exited:
            parser.parse_args(["--robots", bad])
        assert exited.value.code == 2
        assert "argument --robots" in capsys.readouterr().err, bad


def test_run_secrets_with_robots_writes_a_fleet_profile_and_lists_every_user(tmp_path, capsys):
    def secrets(directory: Path, robots: tuple[str, ...]) -> int:
        return run_secrets(
            directory,
            RH0,
            endpoint="tcp/127.0.0.1:7447",
            router_listen=[],
            tls=False,
            tls_names=[],
            seen_as=None,
            router_base=None,
            ros=DEFAULT_ROS,
            robots=robots,
        )

    assert secrets(tmp_path / "fleet", ROBOTS) == 0
    err = capsys.readouterr().err
    assert "for the fleet rh0, rh1" in err
    for identity in fleet_identities(ROBOTS):
        assert f"{identity.user}:" in err and f"{tmp_path / 'fleet' / identity.user}.json5" in err
    assert secrets(tmp_path / "one", ()) == 0
    assert {path.name for path in (tmp_path / "one").iterdir()} == {ROUTER_CONFIG, DICTIONARY} | {
        f"{role}.json5" for role in Role
    }, "one robot's profile: every role's file, control.json5 among them"


@contextmanager
def _fleet_router(
    tmp_path: Path, bridges: dict[str, BridgeGraph] | None = None
) -> Iterator[tuple[Profile, Callable[[Identity], zenoh.Session]]]:
    """A router from a fresh two-robot profile (its bridges ``bridges``, default each robot's name as
    its namespace), and a function that opens a client session as an identity."""
    profile = write_fleet_profile(
        tmp_path / "secrets", ROBOTS, endpoint=f"tcp/127.0.0.1:{free_port()}", bridges=bridges
    )
    with ExitStack() as stack:
        stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.router_config))))

        def open_as(identity: Identity) -> zenoh.Session:
            path = profile.client_config(identity.role, identity.robot)
            return stack.enter_context(zenoh.open(zenoh.Config.from_file(str(path))))

        yield profile, open_as


def test_router_lets_one_robots_credentials_put_only_on_that_robots_keys(tmp_path):
    """Every identity of a two-robot fleet puts on every data key of both robots; what reaches a
    subscriber is exactly what its grants name: rh1's motor puts rh1's torque, never rh0's."""
    with _fleet_router(tmp_path) as (profile, open_as):
        # The witness, an observer, serves rh0's view status, which every identity may query: a
        # session's query reaches it after everything that session put before it, in order.
        witness = open_as(Identity(Role.OBSERVER))
        received: queue.Queue[tuple[str, str]] = queue.Queue()
        witness.declare_subscriber("invent/**", lambda s: received.put((str(s.key_expr), s.payload.to_string())))
        barrier = RH0.view_status
        witness.declare_queryable(barrier, lambda query: query.reply(barrier, b"{}"))
        # The localization may query no view status (it reads no more than it needs): its barrier is
        # its robot's drive/status, served by a witness logged in as that robot's drive.
        barriers = {robot: Keys(robot).status(Service.DRIVE) for robot in ROBOTS}
        for robot, key in barriers.items():
            drive_witness = open_as(Identity(Role.DRIVE, robot))
            drive_witness.declare_subscriber(
                "invent/**", lambda s: received.put((str(s.key_expr), s.payload.to_string()))
            )
            drive_witness.declare_queryable(key, lambda query, key=key: query.reply(key, b"{}"))
        sessions = {identity: open_as(identity) for identity in profile.identities}
        data_keys = [keys.topic(topic) for keys in (RH0, RH1) for topic in Topic]
        publishers = [
            (identity, session.declare_publisher(key)) for identity, session in sessions.items() for key in data_keys
        ]
        wait_until(lambda: all(p.matching_status.matching for _, p in publishers), 20, "the witness to match")
        for identity, publisher in publishers:
            publisher.put(identity.user)
        for identity, session in sessions.items():
            own = barriers[identity.robot] if identity.role is Role.LOCALIZATION and identity.robot else barrier
            assert len([reply.ok for reply in session.get(own, timeout=5.0) if reply.ok]) == 1, identity
        delivered = set()
        while not received.empty():
            delivered.add(received.get())

    expected = {(key, i.user) for i in profile.identities for key in _granted(i, Message.PUT) & set(data_keys)}
    assert delivered == expected
    assert (RH1.motor_torque, "rh1-motor") in delivered and (RH0.motor_torque, "rh0-motor") in delivered
    assert (RH0.motor_torque, "rh1-motor") not in delivered and (RH1.motor_torque, "rh0-motor") not in delivered
    for key, user in delivered:
        robot, _, role = user.rpartition("-")
        if robot:  # a per-robot identity: only ever its own robot's keys
            assert key.startswith(f"invent/{robot}/{role}/") or (
                role == "ros2" and key == Keys(robot).drive_target_velocity
            )
    assert {key for key, user in delivered if user == "sim"} == {
        keys.topic(topic) for keys in (RH0, RH1) for topic in Topic if topic.startswith("sim/")
    }


def test_router_lets_each_robots_bridge_put_only_its_own_robots_ros_topics(tmp_path):
    """Each robot's bridge credentials put on every ROS topic of both bridges (``/clock`` included),
    its own last: once a ROS node (``ros_node``) has every own topic's sample of both, nothing else
    came, so each bridge reached exactly its namespace's topics, and only rh0's bridge ``/clock``."""
    bridges = {"rh0": robot_bridge(DEFAULT_ROS, "rh0"), "rh1": robot_bridge(DEFAULT_ROS, "robot1", False)}
    with _fleet_router(tmp_path, bridges) as (_profile, open_as):
        keys = {robot: {bridge.key(e) for e in bridge.publications.values()} for robot, bridge in bridges.items()}
        every_key = set().union(*keys.values())
        witness = open_as(Identity(Role.ROS_NODE))
        received: queue.Queue[tuple[str, str]] = queue.Queue()
        for key in every_key:
            witness.declare_subscriber(key, lambda s: received.put((str(s.key_expr), s.payload.to_string())))
        sessions = {robot: open_as(Identity(Role.ROS2, robot)) for robot in ROBOTS}
        publishers = {
            robot: {key: session.declare_publisher(key) for key in sorted(every_key, key=lambda k: k in keys[robot])}
            for robot, session in sessions.items()
        }
        wait_until(
            lambda: all(publishers[r][k].matching_status.matching for r in ROBOTS for k in keys[r]), 20, "matching"
        )
        for robot, own in publishers.items():
            for publisher in own.values():  # the other robot's topics first, its own last
                publisher.put(f"{robot}-ros2")
        expected = {(key, f"{robot}-ros2") for robot in ROBOTS for key in keys[robot]}
        delivered: set[tuple[str, str]] = set()

        def all_own_delivered() -> bool:
            while not received.empty():
                delivered.add(received.get())
            return expected <= delivered

        wait_until(all_own_delivered, 10, "each bridge's own topics")
    assert delivered == expected
    assert any(key.startswith("0/clock/") for key, user in delivered if user == "rh0-ros2")
    assert not any(key.startswith("0/clock/") for key, user in delivered if user == "rh1-ros2")


def test_router_lets_one_robots_credentials_neither_call_nor_serve_another_robots_motor_methods(tmp_path):
    """rh1's bridge calls rh1's motor/gui/stop, not rh0's; rh1's motor cannot call rh0's methods nor
    stand in for rh0's motor; the fleet's sim calls every robot's motor/bump/stop, the operator every
    robot's motor/gui/stop."""
    with _fleet_router(tmp_path) as (_profile, open_as):
        calls: list[tuple[str, str]] = []
        serve = partial(noting_replier, calls)

        motors = {robot: open_as(Identity(Role.MOTOR, robot)) for robot in ROBOTS}
        # A second session with rh1's motor credentials tries to serve rh0's stop methods, then rh1's
        # motor status: once that status answers, the router has had (and refused) the impostor's
        # declarations before it. (Its own queries on rh0's keys would be answered inside the
        # session, never crossing the router: the impostor is not the session that calls.)
        impostor = open_as(Identity(Role.MOTOR, "rh1"))
        for family in MethodFamily:
            impostor.declare_queryable(RH0.method(family, Method.STOP), serve("impostor rh1-motor"))
        impostor_status = RH1.status(Service.MOTOR)
        impostor.declare_queryable(impostor_status, lambda query: query.reply(impostor_status, b"impostor"))
        for robot, keys in (("rh0", RH0), ("rh1", RH1)):
            for family in MethodFamily:
                for method in Method:
                    motors[robot].declare_queryable(keys.method(family, method), serve(f"{robot}-motor"))
            status = keys.status(Service.MOTOR)
            motors[robot].declare_queryable(
                status, lambda query, status=status, robot=robot: query.reply(status, robot)
            )
        observer = open_as(Identity(Role.OBSERVER))

        def answers(session: zenoh.Session, key: str) -> list[str]:
            """Every reply of every queryable the router routes the query to."""
            return [
                reply.ok.payload.to_string()
                for reply in session.get(
                    key, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE, timeout=1.0
                )
                if reply.ok is not None
            ]

        for keys, expected in ((RH0, ["rh0"]), (RH1, ["impostor", "rh1"])):
            wait_until(
                lambda k=keys, e=expected: sorted(answers(observer, k.status(Service.MOTOR))) == e,
                10,
                "the motors' statuses",
            )

        def replies(session: zenoh.Session, key: str) -> int:
            return len(answers(session, key))

        bridge_rh1, sim, operator = (
            open_as(Identity(Role.ROS2, "rh1")),
            open_as(Identity(Role.SIM)),
            open_as(Identity(Role.OPERATOR)),
        )
        gui_stop = {robot: keys.method(MethodFamily.GUI, Method.STOP) for robot, keys in (("rh0", RH0), ("rh1", RH1))}
        bump_stop = {robot: keys.method(MethodFamily.BUMP, Method.STOP) for robot, keys in (("rh0", RH0), ("rh1", RH1))}
        assert replies(bridge_rh1, gui_stop["rh0"]) == 0, "rh1's bridge cannot stop rh0"
        assert replies(motors["rh1"], bump_stop["rh0"]) == 0, "rh1's motor cannot call rh0's methods"
        assert replies(motors["rh1"], gui_stop["rh0"]) == 0
        assert calls == [], "nothing reached any motor"
        assert replies(bridge_rh1, gui_stop["rh1"]) == 1, "rh1's bridge stops rh1"
        for robot in ROBOTS:
            assert replies(sim, bump_stop[robot]) == 1, f"the fleet's sim bump-stops {robot}"
            assert replies(operator, gui_stop[robot]) == 1, f"the operator stops {robot}"
            assert replies(sim, gui_stop[robot]) == 0, "the sim calls only the bump family"
        assert calls == [
            ("rh1-motor", gui_stop["rh1"]),
            ("rh0-motor", bump_stop["rh0"]),
            ("rh0-motor", gui_stop["rh0"]),
            ("rh1-motor", bump_stop["rh1"]),
            ("rh1-motor", gui_stop["rh1"]),
        ], "each call reached its own robot's motor, never the impostor"


def test_router_lets_one_robots_bridge_reach_only_its_own_robots_goals_and_the_operator_every_robots(tmp_path):
    """Each robot's drive serves its goal queryables; rh1's bridge reaches rh1's, never rh0's; the
    fleet's operator reaches both; rh1's drive credentials cannot serve rh0's goals (an impostor is
    never routed to); the observer reaches none."""
    with _fleet_router(tmp_path) as (_profile, open_as):
        calls: list[tuple[str, str]] = []
        serve = partial(noting_replier, calls, reply=GOAL_REFUSED)

        impostor = open_as(Identity(Role.DRIVE, "rh1"))
        for key in sorted(_goals(RH0)):
            impostor.declare_queryable(key, serve("impostor rh1-drive"))
        drives = {robot: open_as(Identity(Role.DRIVE, robot)) for robot in ROBOTS}
        for robot, keys in (("rh0", RH0), ("rh1", RH1)):
            for key in sorted(_goals(keys)):
                drives[robot].declare_queryable(key, serve(f"{robot}-drive"))
            status = keys.status(Service.DRIVE)
            drives[robot].declare_queryable(status, lambda query, status=status: query.reply(status, b"{}"))
        observer = open_as(Identity(Role.OBSERVER))
        for keys in (RH0, RH1):
            wait_until(
                lambda k=keys: [r for r in observer.get(k.status(Service.DRIVE), timeout=1.0) if r.ok is not None],
                10,
                "the drives' statuses",
            )
        callers = {
            "rh1-ros2": open_as(Identity(Role.ROS2, "rh1")),
            "operator": open_as(Identity(Role.OPERATOR)),
            "observer": observer,
        }
        reached = {
            (caller, key)
            for caller, session in callers.items()
            for key in sorted(_goals(RH0) | _goals(RH1))
            for reply in session.get(key, timeout=1.0)
            if reply.ok is not None
        }
    assert reached == {("rh1-ros2", key) for key in _goals(RH1)} | {
        ("operator", key) for key in _goals(RH0) | _goals(RH1)
    }, "rh1's bridge: rh1's goals only; the operator: every robot's; the observer: none"
    assert sorted(calls) == sorted(
        [("rh1-drive", key) for key in _goals(RH1) for _caller in ("rh1-ros2", "operator")]
        + [("rh0-drive", key) for key in _goals(RH0)]
    ), "each call reached its own robot's drive, never the impostor"


def test_invent_secrets_robots_writes_a_fleet_profile_and_a_bad_name_exits_2_naming_the_flag(tmp_path):
    result = run_invent("secrets", str(tmp_path / "fleet"), "--robots", "rh0,rh1")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "fleet" / "rh1-motor.json5").is_file() and (tmp_path / "fleet" / "sim.json5").is_file()
    assert not (tmp_path / "fleet" / "motor.json5").exists()
    assert not (tmp_path / "fleet" / "control.json5").exists(), "a fleet has no control role"
    for bad in ("rh0,rh/1", "rh0,rh0", ""):
        result = run_invent("secrets", str(tmp_path / "bad"), "--robots", bad)
        assert result.returncode == 2 and "argument --robots" in result.stderr, (bad, result.stderr)
    assert not (tmp_path / "bad").exists()
