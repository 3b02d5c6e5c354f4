"""Per-robot credentials (issue 26) at the router, with real sessions: one robot's credentials cannot
put on, call or serve the methods of another robot, nor its bridge reach another robot's topics and
goals; the fleet's sim and operator reach every robot (tests/test_security_fleet.py: the fleet's
profile, its users and grants).
"""

from __future__ import annotations

import queue
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from functools import partial
from pathlib import Path

import zenoh

from schemas.keys import Keys, Service
from schemas.topics import Method, MethodFamily, Topic
from services.ros2.graph import BridgeGraph
from services.security import (
    DEFAULT_ROS,
    Identity,
    Message,
    Profile,
    Role,
    robot_bridge,
    write_fleet_profile,
)
from tests.goal_standin import GOAL_REFUSED
from tests.harness import free_port, noting_replier, run_invent, wait_until
from tests.test_security_fleet import RH0, RH1, ROBOTS, _goals, _granted


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
        # The witness, an observer, reads every key and serves rh0's view status: a tool's session
        # asks it after its puts; a service's session (which may query no status) is asked its own
        # by the witness. Query and reply cross the router after what their sender put before them.
        witness = open_as(Identity(Role.OBSERVER))
        received: queue.Queue[tuple[str, str]] = queue.Queue()
        witness.declare_subscriber("invent/**", lambda s: received.put((str(s.key_expr), s.payload.to_string())))
        barrier = RH0.view_status
        witness.declare_queryable(barrier, lambda query: query.reply(barrier, b"{}"))
        sessions = {identity: open_as(identity) for identity in profile.identities}
        data_keys = [keys.topic(topic) for keys in (RH0, RH1) for topic in Topic]
        publishers = [
            (identity, session.declare_publisher(key)) for identity, session in sessions.items() for key in data_keys
        ]
        wait_until(lambda: all(p.matching_status.matching for _, p in publishers), 20, "the witness to match")
        for identity, publisher in publishers:
            publisher.put(identity.user)
        for identity, session in sessions.items():
            if identity.role in (Role.OPERATOR, Role.OBSERVER, Role.ROS_NODE):
                assert len([reply.ok for reply in session.get(barrier, timeout=5.0) if reply.ok]) == 1, identity
                continue
            own = Keys(identity.robot or ROBOTS[0]).status(Service(identity.role.value))
            session.declare_queryable(own, lambda query, own=own: query.reply(own, b"{}"))
            wait_until(lambda own=own: [r for r in witness.get(own, timeout=1.0) if r.ok], 10, f"{identity}'s status")
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
