"""The services' declared interfaces (services/interfaces.py): they are whole and consistent, a node
refuses a key its service did not declare (real zenoh sessions), the roles' grants are made of
them, and the docs' loop diagram is the one they make."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader

from schemas.interface import Interface, Participation
from schemas.keys import LOOP_SERVICES, Keys, Service
from schemas.topics import Topic
from services import interfaces
from services.config import Config
from services.launch import loop_diagram
from services.recording.record import write_run_recording
from services.runtime.declared import DeclaredKeys, UndeclaredKey
from services.runtime.inputs import Delivery
from services.runtime.node import Node
from services.security import Flow, Message, Role, grants
from tests.harness import peer_session, running_router

KEYS = Keys("declared")
CONFIG = Config()
EVERY_SERVICE = (*LOOP_SERVICES, Service.ROS2)


def _ingress(role: Role, message: Message, **described) -> set[str]:
    return {
        key
        for grant in grants(role, KEYS, **described)
        if message in grant.messages and grant.flow is Flow.INGRESS
        for key in grant.key_exprs
    }


def test_every_key_a_loop_service_subscribes_or_queries_another_loop_service_publishes_or_serves():
    loop = interfaces.loop(KEYS, CONFIG)
    published = {key for interface in loop for key in interface.publishes}
    served = {key for interface in loop for key in (*interface.serves, *interface.latched_published(KEYS))}
    for interface in loop:
        assert set(interface.subscribes) <= published, interface.service
        statuses = {KEYS.status(service) for service in Service}
        assert set(interface.queries) - statuses <= served, interface.service


def test_each_service_publishes_only_under_its_own_name_and_a_participant_publishes_its_output():
    for service in EVERY_SERVICE:
        interface = interfaces.declared(service, KEYS, CONFIG)
        own = interface.publishes if service is not Service.ROS2 else ()  # the bridge forwards twists as the drive
        assert all(key.startswith(f"{KEYS.prefix}/{service}/") for key in own), service
        if interface.participates is not None:
            assert interface.participates.output in interface.publishes, service


@pytest.mark.parametrize("mode", ["stub", "amcl", "none"])
def test_the_localization_declares_what_its_mode_reads_and_only_the_stub_the_ground_truth(mode):
    declared = interfaces.localization_in(KEYS, mode, 1.0)
    assert (KEYS.motor_sim_pose_localization in declared.subscribes) == (mode == "stub")
    assert KEYS.sim_body_pose not in declared.subscribes
    assert (declared.participates is None) == (mode == "none")


def test_a_participant_holds_its_ticks_at_its_rate_and_the_bridge_observes_at_its_rates():
    drive = interfaces.declared(Service.DRIVE, KEYS, CONFIG)
    assert drive.ticks(KEYS) == (KEYS.ticks(Service.DRIVE, CONFIG.drive.rate),)
    bridge = interfaces.declared(Service.ROS2, KEYS, CONFIG)
    assert bridge.ticks(KEYS) == () and bridge.observes == tuple(
        sorted({CONFIG.ros2.publish_rate, CONFIG.ros2.clock_rate})
    )


@pytest.mark.parametrize("service", LOOP_SERVICES)
def test_a_service_roles_grants_are_exactly_its_declared_puts_subscriptions_and_queryables(service):
    declared = interfaces.declared(service, KEYS, CONFIG)
    role = Role(service.value)
    assert _ingress(role, Message.PUT) == set(declared.publishes)
    assert _ingress(role, Message.DECLARE_SUBSCRIBER) == set(declared.subscribes)
    served = {KEYS.status(service), *declared.serves, *declared.latched_published(KEYS)}
    assert _ingress(role, Message.DECLARE_QUERYABLE) == served
    assert _ingress(role, Message.QUERY) == set(declared.queries)


def test_the_sim_may_follow_the_user_services_of_its_profile_and_no_one_else():
    followed = _ingress(Role.SIM, Message.DECLARE_SUBSCRIBER, followed=["odometer"])
    assert followed - _ingress(Role.SIM, Message.DECLARE_SUBSCRIBER) == {f"{KEYS.prefix}/odometer/**"}
    assert KEYS.status("odometer") in _ingress(Role.SIM, Message.QUERY, followed=["odometer"])
    assert _ingress(Role.MOTOR, Message.DECLARE_SUBSCRIBER, followed=["odometer"]) == set(
        interfaces.declared(Service.MOTOR, KEYS, CONFIG).subscribes
    )


TOPIC_KEYS = st.sets(st.sampled_from([KEYS.topic(topic) for topic in Topic]))


@given(publishes=TOPIC_KEYS, subscribes=TOPIC_KEYS)
def test_declared_keys_let_through_exactly_what_is_declared(publishes, subscribes):
    interface = Interface(Service.ODOMETRY, publishes=tuple(sorted(publishes)), subscribes=tuple(sorted(subscribes)))
    declared = DeclaredKeys(interface, KEYS)
    for topic in Topic:
        key = KEYS.topic(topic)
        for check, allowed in ((declared.publish, publishes), (declared.subscribe, subscribes)):
            if key in allowed:
                check(key)
            else:
                with pytest.raises(UndeclaredKey, match=key):
                    check(key)


def test_a_key_expression_inside_a_declared_one_and_keys_outside_invent_pass_and_no_declaration_checks_nothing():
    declared = DeclaredKeys(Interface(Service.DRIVE, subscribes=(f"{KEYS.prefix}/sim/**",)), KEYS)
    declared.subscribe(KEYS.sim_scan)
    declared.subscribe(f"{KEYS.prefix}/sim/*")
    declared.subscribe("0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_abc")  # a ROS key: the ROS graph's
    with pytest.raises(UndeclaredKey):
        declared.subscribe(KEYS.everything)
    DeclaredKeys(None, KEYS).publish(KEYS.motor_torque)


def test_the_sim_follows_a_user_participants_output_and_status_but_no_undeclared_built_in_key():
    declared = DeclaredKeys(interfaces.declared(Service.SIM, KEYS, CONFIG), KEYS)
    declared.subscribe(KEYS.own("odometer", "distance"))
    declared.query(KEYS.status("odometer"))
    with pytest.raises(UndeclaredKey):
        declared.subscribe(KEYS.odometry_pose)


def test_a_node_refuses_to_publish_subscribe_serve_or_query_a_key_its_service_did_not_declare():
    interface = Interface(
        Service.ODOMETRY,
        publishes=(KEYS.odometry_pose,),
        subscribes=(KEYS.motor_wheel_angles,),
        serves=(KEYS.odometry_set_pose,),
        queries=(KEYS.motor_state,),
        participates=Participation(10.0, KEYS.odometry_pose),
    )
    with running_router() as endpoint, peer_session(endpoint) as session:
        node = Node(session, KEYS, Service.ODOMETRY, interface=interface)
        try:
            node.publisher(KEYS.odometry_pose)
            node.subscribe_bytes(KEYS.motor_wheel_angles, lambda _p, _a: None, Delivery.QUEUED)
            node.queryable(KEYS.odometry_set_pose, lambda _payload: None)
            node.querier(KEYS.motor_state)
            with pytest.raises(UndeclaredKey, match="odometry publishes invent/declared/motor/torque"):
                node.publisher(KEYS.motor_torque)
            with pytest.raises(UndeclaredKey, match="subscribes"):
                node.subscribe_bytes(KEYS.sim_body_pose, lambda _p, _a: None, Delivery.QUEUED)
            with pytest.raises(UndeclaredKey, match="serves"):
                node.queryable(KEYS.drive_goal_send, lambda _payload: None)
            with pytest.raises(UndeclaredKey, match="queries"):
                node.querier(KEYS.drive_goal_send)
        finally:
            node.close()


def test_the_docs_loop_diagram_is_the_one_the_declarations_make():
    document = loop_diagram.ARCHITECTURE.read_text()
    assert loop_diagram.replaced(document, loop_diagram.render()) == document, (
        "docs/architecture.md's loop diagram is stale: python -m services.launch.loop_diagram"
    )
    assert 'drive -.->|"drive/target_velocity (tick barrier)"| sim' in loop_diagram.render()


def test_a_runs_recording_holds_a_channel_for_every_key_the_loop_declares_it_publishes_from_its_start(tmp_path):
    journals = tmp_path / "journals"
    journals.mkdir()  # a run that published nothing yet: the channels are there all the same
    written = write_run_recording(journals, tmp_path / "run.mcap", CONFIG)
    with written.parts[0].open("rb") as recording:
        summary = make_reader(recording).get_summary()
    assert summary is not None
    topics = [channel.topic for channel in sorted(summary.channels.values(), key=lambda channel: channel.id)]
    declared = interfaces.published(Keys(CONFIG.robot.name), CONFIG)
    assert topics[: len(declared)] == list(declared)
    assert Keys(CONFIG.robot.name).motor_torque in declared and Keys(CONFIG.robot.name).sim_world in declared


@pytest.mark.parametrize(("mode", "ticking"), [("stub", 2), ("none", 1)])
def test_the_lockstep_participants_the_launcher_waits_for_are_the_drive_and_a_localization_with_fixes(mode, ticking):
    config = msgspec.structs.replace(CONFIG, localization=msgspec.structs.replace(CONFIG.localization, mode=mode))
    participants = interfaces.participants(KEYS, config, drive_rate_hz=None)
    assert [one.service for one in participants] == [Service.DRIVE, Service.LOCALIZATION][:ticking]
    assert participants[0].ticks(KEYS) == (KEYS.ticks(Service.DRIVE, CONFIG.drive.rate),)
    driven_by_a_user_service = interfaces.participants(KEYS, config, drive_rate_hz=4.0)[0]
    assert driven_by_a_user_service.ticks(KEYS) == (KEYS.ticks(Service.DRIVE, 4.0),), "the drive's token at its rate"
