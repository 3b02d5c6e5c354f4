"""The secure profile's router with the ROS 2 bridge's role and ROS nodes' (real sessions): the bridge
reaches ROS nodes only on its own topics, tokens and latched caches, calls only its methods, and serves
its NavigateToPose action, which no other role may impersonate (tests/test_security_router.py: the
services' and tools' roles)."""

from __future__ import annotations

import queue
from collections.abc import Callable

import zenoh
import zenoh.ext

from schemas.keys import Service, all_robots_status
from schemas.topics import Method, MethodFamily
from services.ros2.graph import MOTOR_SERVICES, PUBLICATIONS
from services.security import (
    DEFAULT_ROS,
    Role,
)
from tests.harness import wait_until
from tests.test_security import KEYS
from tests.test_security_router import _secured_router


def test_router_lets_the_ros2_bridge_put_only_its_ros_keys_and_call_only_its_methods(tmp_path):
    """Real sessions through a secured router: the bridge's role reaches ROS nodes on its own topics,
    its tokens and its latched cache, and nowhere else; ROS nodes reach its /cmd_vel."""
    from tests import ros_client

    ros = DEFAULT_ROS
    odom, description = ros.key(PUBLICATIONS["odom"]), ros.key(PUBLICATIONS["robot_description"])
    cmd_vel = ros_client.topic_key(0, "cmd_vel", "geometry_msgs/msg/Twist")
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        bridge, ros_node, motor = open_as(Role.ROS2), open_as(Role.ROS_NODE), open_as(Role.MOTOR)
        at_node: queue.Queue[str] = queue.Queue()
        ros_node.declare_subscriber("0/**", lambda sample: at_node.put(str(sample.key_expr)))
        ros_node.declare_subscriber(odom, lambda _sample: None)  # as rmw_zenoh subscribes: the topic's key
        at_bridge: queue.Queue[str] = queue.Queue()
        bridge.declare_subscriber(cmd_vel, lambda sample: at_bridge.put(str(sample.key_expr)))
        at_motor: queue.Queue[str] = queue.Queue()  # an observer's view: it reads every key
        open_as(Role.OBSERVER).declare_subscriber(KEYS.everything, lambda sample: at_motor.put(str(sample.key_expr)))
        calls: list[str] = []
        for method in Method:
            key = KEYS.method(MethodFamily.GUI, method)
            motor.declare_queryable(
                key, lambda query: (calls.append(str(query.key_expr)), query.reply(query.key_expr, b"{}"))
            )
        publisher = bridge.declare_publisher(odom)
        wait_until(lambda: publisher.matching_status.matching, 10, "the ROS node's subscription to match")
        for forbidden in (cmd_vel, odom.replace("/odom/", "/elsewhere/"), KEYS.motor_torque):
            bridge.put(forbidden, b"forged")
        bridge.put(KEYS.drive_target_velocity, b"a target")
        publisher.put(b"odom")
        assert at_node.get(timeout=5.0) == odom, "its own topic reaches the ROS node, the forgeries before it do not"
        assert at_motor.get(timeout=5.0) == KEYS.drive_target_velocity, "and drive/target_velocity reaches a reader"
        assert at_node.empty() and at_motor.empty()

        wait_until(lambda: ros_node.declare_publisher(cmd_vel).matching_status.matching, 10, "the bridge's /cmd_vel")
        ros_node.put(cmd_vel, b"twist")
        assert at_bridge.get(timeout=5.0) == cmd_vel, "a ROS node's /cmd_vel reaches the bridge"

        status = KEYS.status(Service.ROS2)
        bridge.declare_queryable(status, lambda query: query.reply(status, b"{}"))
        observer = open_as(Role.OBSERVER)
        wait_until(
            lambda: [r for r in observer.get(all_robots_status(), timeout=1.0) if r.ok is not None],
            10,
            "the bridge's status, asked as invent/*/*/status",
        )
        for method in Method:
            list(bridge.get(KEYS.method(MethodFamily.GUI, method), timeout=1.0))
        assert sorted(calls) == sorted(KEYS.method(MethodFamily.GUI, method) for method in MOTOR_SERVICES)

        tokens = [  # held: a token object dropped is a token withdrawn
            bridge.liveliness().declare_token(f"@ros2_lv/0/{bridge.zid()}/0/0/NN/%/%/{name}")
            for name in ("invent_bridge", "someone_else")
        ]
        seen = wait_until(
            lambda: [str(r.ok.key_expr) for r in ros_node.liveliness().get("@ros2_lv/0/**", timeout=1.0) if r.ok],
            10,
            "the bridge's node token",
        )
        assert [token.rsplit("/", 1)[1] for token in seen] == ["invent_bridge"] and len(tokens) == 2

        cached = zenoh.ext.declare_advanced_publisher(  # as the bridge declares a latched topic
            bridge,
            description,
            cache=zenoh.ext.CacheConfig(1),
            publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=1.0),
        )
        cached.put(b"<robot/>")
        late: queue.Queue[bytes] = queue.Queue()
        late_subscriber = zenoh.ext.declare_advanced_subscriber(
            ros_node,
            description,
            lambda sample: late.put(sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        assert late.get(timeout=10.0) == b"<robot/>", "a late ROS node gets the latched topic through the router"
        late_subscriber.undeclare()


def test_router_lets_the_ros2_bridge_serve_its_navigate_to_pose_action_and_no_other_role_impersonate_it(tmp_path):
    """Real sessions through a secured router: a ROS node's send_goal reaches the bridge's queryable
    and gets its reply, an impostor's (the operator's) same queryable is never routed to; the
    bridge's status (a transient-local advanced publisher, as the bridge declares it) reaches a late
    ROS node from its cache, its feedback a subscribed one."""
    from services.ros2.graph import ACTION_SERVICES, ACTION_TOPICS, ActionService, ActionTopic
    from tests import ros_services

    ros = DEFAULT_ROS
    send_goal = ros.key(ACTION_SERVICES[ActionService.SEND_GOAL])
    status, feedback = (ros.key(ACTION_TOPICS[topic]) for topic in (ActionTopic.STATUS, ActionTopic.FEEDBACK))
    assert send_goal == ros_services.action_key(0, "/navigate_to_pose", "send_goal")
    with _secured_router(tmp_path, tls=False) as (_profile, open_as):
        bridge, ros_node, impostor = open_as(Role.ROS2), open_as(Role.ROS_NODE), open_as(Role.OPERATOR)
        served: list[str] = []

        def serve(who: str) -> Callable[[zenoh.Query], None]:
            def answer(query: zenoh.Query) -> None:
                served.append(who)
                query.reply(query.key_expr, who.encode())

            return answer

        impostor.declare_queryable(send_goal, serve("impostor"))
        bridge.declare_queryable(send_goal, serve("bridge"), complete=True)
        replies = wait_until(
            lambda: [r.ok.payload.to_bytes() for r in ros_node.get(send_goal, timeout=1.0) if r.ok is not None],
            10,
            "the bridge's send_goal",
        )
        assert replies == [b"bridge"] and set(served) == {"bridge"}

        heard: queue.Queue[bytes] = queue.Queue()
        ros_node.declare_subscriber(feedback, lambda sample: heard.put(sample.payload.to_bytes()))
        publisher = bridge.declare_publisher(feedback)
        wait_until(lambda: publisher.matching_status.matching, 10, "the ROS node's feedback subscription")
        publisher.put(b"feedback")
        assert heard.get(timeout=5.0) == b"feedback"
        cached = zenoh.ext.declare_advanced_publisher(
            bridge,
            status,
            cache=zenoh.ext.CacheConfig(1),
            publisher_detection=True,
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=1.0),
        )
        cached.put(b"status")
        late: queue.Queue[bytes] = queue.Queue()
        late_subscriber = zenoh.ext.declare_advanced_subscriber(
            ros_node,
            status,
            lambda sample: late.put(sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        assert late.get(timeout=10.0) == b"status", "a late ROS node gets the action's status through the router"
        late_subscriber.undeclare()
        cached.undeclare()
