"""Per-robot credentials (issue 26): a fleet's profile, its users and grants per robot
(tests/test_security_fleet_router.py: the router's access control with real sessions)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import stat
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
    Role,
    fleet_grants,
    fleet_identities,
    fleet_robots,
    grants,
    robot_bridge,
    write_fleet_profile,
    write_profile,
)

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
    } | _goals(RH1), "an initial pose only for a robot whose localization is amcl"
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
    # each robot's bump stop, and the status of its motor and lockstep participants at the start
    assert _granted(sim, Message.QUERY) == {
        key
        for keys in (RH0, RH1)
        for key in (
            keys.method(MethodFamily.BUMP, Method.STOP),
            *(keys.status(service) for service in (Service.MOTOR, Service.DRIVE, Service.LOCALIZATION)),
        )
    }
    assert not _granted(sim, Message.QUERY) & (_methods(RH0, MethodFamily.GUI) | _methods(RH1, MethodFamily.GUI))
    assert _granted(sim, Message.LIVELINESS_TOKEN) == {keys.alive(Service.SIM) for keys in (RH0, RH1)}


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
