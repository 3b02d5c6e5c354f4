"""The secure profile: roles and their grants, and the files `invent secrets` writes
(tests/test_security_router.py: the router's access control with real sessions, `invent up --secure`)."""

from __future__ import annotations

import json
import stat

import zenoh
import zenoh.ext

from schemas.keys import LOOP_SERVICES, Keys, Service, all_robots_status
from schemas.topics import LATCHED_TOPICS, Method, MethodFamily, Topic
from services import interfaces
from services.config import Config
from services.ros2.graph import MOTOR_SERVICES, PUBLICATIONS, BridgeGraph
from services.security import (
    CA_CERTIFICATE,
    DEFAULT_ROS,
    DICTIONARY,
    TLS_DIRECTORY,
    Flow,
    Message,
    Role,
    grants,
    write_profile,
)
from tests.harness import run_invent

KEYS = Keys("secured")
FORGED_VX = 0.4321
"""A forward speed nothing in the tests' loop ever commands: seeing it means a forged put got through."""


def _granted(role: Role, message: Message) -> set[str]:
    """The key expressions on which ``role`` may send ``message`` (its ingress at the router)."""
    return {
        key
        for grant in grants(role, KEYS)
        if message in grant.messages and grant.flow is Flow.INGRESS
        for key in grant.key_exprs
    }


def _put_keys(role: Role) -> set[str]:
    return _granted(role, Message.PUT)


def _queried_keys(role: Role) -> set[str]:
    return _granted(role, Message.QUERY)


LATCHED = {KEYS.topic(topic) for topic in LATCHED_TOPICS}
"""What a latched publisher last published answers queries on its key: every role may ask."""


def _methods(family: MethodFamily) -> set[str]:
    return {KEYS.method(family, method) for method in Method}


GOALS = {KEYS.drive_goal_send, KEYS.drive_goal_cancel}
"""The drive's goal queryables: sending and canceling goals is a right of its own."""


def test_each_service_role_puts_exactly_what_its_interface_declares_all_under_its_own_name():
    for service in LOOP_SERVICES:
        declared = set(interfaces.declared(service, KEYS, Config()).publishes)
        assert _put_keys(Role(service.value)) == declared, service
        assert declared <= {KEYS.topic(topic) for topic in Topic if topic.split("/")[0] == service}, service
    # the stub localization publishes no particles (amcl does: tests/test_security_localization.py)
    assert _put_keys(Role.LOCALIZATION) == {KEYS.localization_pose}
    assert _put_keys(Role.CONTROL) == _put_keys(Role.SIM) | _put_keys(Role.MOTOR), "the sim and the motor, composed"
    assert _put_keys(Role.OPERATOR) == {KEYS.drive_target_velocity, KEYS.run_summary}, "the run's summary: invent up"
    assert _put_keys(Role.OBSERVER) == set()


def test_the_ros2_role_puts_only_its_ros_keys_and_targets_and_calls_only_the_trigger_methods():
    from services.ros2.graph import ACTION_SERVICES, ACTION_TOPICS, ActionTopic

    ros = DEFAULT_ROS
    published = {ros.key(entity) for entity in (*PUBLICATIONS.values(), *ACTION_TOPICS.values())}
    cache_keys = {
        f"{ros.key(PUBLICATIONS[name])}/@adv/**" for name in ("tf_static", "robot_description", "map", "costmap")
    }
    cache_keys.add(f"{ros.key(ACTION_TOPICS[ActionTopic.STATUS])}/@adv/**")
    assert _put_keys(Role.ROS2) == published | cache_keys | {KEYS.drive_target_velocity}
    assert all(key.startswith("0/") for key in published)
    # the drive's map and plan, latched, are asked for their last message; an initial pose only with amcl
    latched = {KEYS.drive_map, KEYS.drive_plan}
    trigger_methods = {KEYS.method(MethodFamily.GUI, method) for method in MOTOR_SERVICES}
    assert _queried_keys(Role.ROS2) == trigger_methods | GOALS | latched
    amcl = {
        key for g in grants(Role.ROS2, KEYS, localization="amcl") if Message.QUERY in g.messages for key in g.key_exprs
    }
    assert KEYS.localization_initial_pose in amcl
    assert KEYS.method(MethodFamily.GUI, Method.SET_PD_GAIN) not in _queried_keys(Role.ROS2)
    served = _granted(Role.ROS2, Message.DECLARE_QUERYABLE)
    services = (*MOTOR_SERVICES.values(), *ACTION_SERVICES.values(), *ros.odometry_services.values())
    assert served == {KEYS.status(Service.ROS2)} | {ros.key(e) for e in services} | cache_keys


def test_the_ros_roles_are_granted_the_domain_and_namespace_they_are_written_for():
    ros = BridgeGraph(7, "/rh1", "invent_bridge")
    bridge = {key for grant in grants(Role.ROS2, KEYS, ros) for key in grant.key_exprs}
    assert ros.key(PUBLICATIONS["odom"]) == "7/rh1/odom/" + ros.key(PUBLICATIONS["odom"]).split("/", 3)[3]
    assert ros.key(PUBLICATIONS["odom"]) in bridge and DEFAULT_ROS.key(PUBLICATIONS["odom"]) not in bridge
    assert "@ros2_lv/7/*/*/*/*/*/%rh1/invent_bridge/**" in bridge
    node = {key for grant in grants(Role.ROS_NODE, KEYS, ros) for key in grant.key_exprs}
    assert {"7/**", "7/**/@adv/**", "@ros2_lv/7/**"} <= node and not any(key.startswith("0/") for key in node)


def test_only_the_operator_the_sim_the_control_path_and_the_ros2_bridge_query_motor_methods():
    status = {all_robots_status()} | LATCHED
    localize = {KEYS.localization_initial_pose, KEYS.localization_global_localization}
    assert _queried_keys(Role.OPERATOR) == status | _methods(MethodFamily.GUI) | GOALS | localize | {
        KEYS.odometry_set_pose
    }
    # the sim: the bump stop, and the status of the motor and the lockstep participants at the start
    participants = {KEYS.status(service) for service in (Service.MOTOR, Service.DRIVE, Service.LOCALIZATION)}
    assert (
        _queried_keys(Role.SIM)
        == _queried_keys(Role.CONTROL)
        == participants | {KEYS.method(MethodFamily.BUMP, Method.STOP)}
    )
    assert _queried_keys(Role.OBSERVER) == status
    assert _queried_keys(Role.DRIVE) == {KEYS.motor_state}, "the motor's state, latched"
    for role in (Role.MOTOR, Role.ODOMETRY, Role.LOCALIZATION):
        assert _queried_keys(role) == set(), role
    assert _queried_keys(Role.ROS_NODE) == status | {"0/**", "0/**/@adv/**", "@ros2_lv/0/**"}


def test_only_the_motor_and_the_control_path_serve_the_methods_and_each_service_its_status_and_latched_keys():
    methods = _methods(MethodFamily.GUI) | _methods(MethodFamily.BUMP)
    for role in Role:
        served = _granted(role, Message.DECLARE_QUERYABLE)
        if role is Role.MOTOR:
            assert served == {KEYS.status(Service.MOTOR), KEYS.motor_state} | methods
        elif role is Role.CONTROL:
            sim = {KEYS.status(Service.SIM), KEYS.sim_world}
            motor = {KEYS.status(Service.MOTOR), KEYS.motor_state} | methods
            assert served == sim | motor | {KEYS.control_status}, "the sim's, the motor's and the process's status"
        elif role is Role.OPERATOR:
            assert served == set(), role
        elif role is Role.OBSERVER:
            assert served == {KEYS.view_status}, "invent view's status"
        elif role is Role.ROS_NODE:
            assert served == {"0/**", "0/**/@adv/**", "@ros2_lv/0/**"}, "a ROS node serves in its domain only"
        elif role is Role.ROS2:
            continue  # test_the_ros2_role_puts_only_its_ros_keys_and_targets_and_calls_only_the_trigger_methods
        else:
            service = Service(role.value)
            own = GOALS if role is Role.DRIVE else {KEYS.odometry_set_pose} if role is Role.ODOMETRY else set()
            assert served == {KEYS.status(service)} | {key for key in LATCHED if f"/{service}/" in key} | own, role


def test_sending_and_canceling_goals_is_the_operators_and_the_bridges_right_and_only_the_drive_serves_them():
    for role in Role:
        queried, served = _queried_keys(role) & GOALS, _granted(role, Message.DECLARE_QUERYABLE) & GOALS
        assert queried == (GOALS if role in (Role.OPERATOR, Role.ROS2) else set()), role
        assert served == (GOALS if role is Role.DRIVE else set()), role
    assert not any(GOALS & set(grant.key_exprs) for grant in grants(Role.OBSERVER, KEYS)), "the observer: nothing"


def test_the_control_role_is_granted_exactly_the_union_of_the_sims_and_the_motors():
    """``invent control`` runs the sim and the motor on one session: for every message and flow, the
    key expressions granted to ``control`` are the sim's and the motor's together, and nothing more
    but the process's own status (``control/status``)."""

    def keys(role: Role, message: Message, flow: Flow) -> set[str]:
        return {key for g in grants(role, KEYS) if message in g.messages and g.flow is flow for key in g.key_exprs}

    for message in Message:
        for flow in Flow:
            union = keys(Role.SIM, message, flow) | keys(Role.MOTOR, message, flow)
            if flow is Flow.INGRESS and message in (Message.DECLARE_QUERYABLE, Message.REPLY):
                union.add(KEYS.control_status)
            assert keys(Role.CONTROL, message, flow) == union, (message, flow)
    assert KEYS.drive_target_velocity not in _put_keys(Role.CONTROL)
    assert not _queried_keys(Role.CONTROL) & (_methods(MethodFamily.GUI) | GOALS), "no gui methods, no goals"
    merged = [(grant.messages, grant.flow) for grant in grants(Role.CONTROL, KEYS)]
    assert len(merged) == len(set(merged)), "one rule per message set and flow"


def test_profile_files_are_private_and_complete_zenoh_configurations(tmp_path):
    profile = write_profile(tmp_path / "secrets", KEYS, endpoint="tcp/127.0.0.1:7447")
    assert stat.S_IMODE(profile.directory.stat().st_mode) == 0o700
    files = list(profile.directory.iterdir())
    assert {path.name for path in files} == {"router.json5", DICTIONARY} | {f"{role}.json5" for role in Role}
    assert "control.json5" in {path.name for path in files}, "invent control's credentials"
    assert all(stat.S_IMODE(path.stat().st_mode) == 0o600 for path in files)
    users = dict(line.split(":") for line in (profile.directory / DICTIONARY).read_text().splitlines())
    assert set(users) == {str(role) for role in Role}
    for role in Role:
        config = json.loads(str(zenoh.Config.from_file(str(profile.client_config(role)))))
        assert config["mode"] == "client"
        assert config["connect"]["endpoints"] == ["tcp/127.0.0.1:7447"]
        assert config["transport"]["auth"]["usrpwd"]["user"] == str(role)
        assert config["transport"]["auth"]["usrpwd"]["password"] == users[str(role)]
    router = json.loads(str(zenoh.Config.from_file(str(profile.router_config))))
    assert router["mode"] == "router" and router["access_control"]["default_permission"] == "deny"
    again = write_profile(tmp_path / "secrets", KEYS, endpoint="tcp/127.0.0.1:7447")
    assert (again.directory / DICTIONARY).read_text() != "\n".join(f"{u}:{p}" for u, p in users.items()) + "\n"


def test_invent_secrets_writes_a_profile_and_rejects_a_bad_endpoint(tmp_path):
    result = run_invent("secrets", str(tmp_path / "ok"), "--robot", KEYS.robot, "--tls")
    assert result.returncode == 0, result.stderr
    assert "tls/127.0.0.1:7447" in result.stderr
    assert (tmp_path / "ok" / TLS_DIRECTORY / CA_CERTIFICATE).exists()
    bad = run_invent("secrets", str(tmp_path / "bad"), "--endpoint", "udp-ish/nowhere")
    assert bad.returncode == 2 and "udp-ish/nowhere" in bad.stderr
