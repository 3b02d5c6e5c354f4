"""invent router / echo / call / status against real zenoh, each tool in its own process."""

import json
import threading

import pytest

from schemas import BadInput, Keys, Method, MethodFamily, Service, Time, TimedDoubleSeq
from services.runtime.node import Node
from tests.harness import Collector, InventProcess, free_port, json_lines, open_peer, run_invent, wait_until
from tests.status_samples import StateStatus


@pytest.fixture
def node(session):
    """A service node spinning on its own thread, as a service would."""
    node = Node(session, Keys("rh0"), Service.MOTOR, status=lambda: StateStatus(state="idle"))
    stop = threading.Event()
    spinner = threading.Thread(target=node.serve, args=(stop, lambda: False))
    spinner.start()
    yield node
    stop.set()
    spinner.join()
    node.close()


def test_echo_through_an_invent_router_prints_decoded_samples():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys("rh0")
    with InventProcess("router", "--listen", endpoint) as router:
        with InventProcess("echo", keys.everything, "--count", "2", "--connect", endpoint) as echo:
            publisher_session = open_peer(endpoint)
            try:
                angles = publisher_session.declare_publisher(keys.sim_wheel_angles, encoding="application/json")
                velocity = publisher_session.declare_publisher(keys.drive_target_velocity)
                wait_until(lambda: angles.matching_status.matching, 20, "invent echo to subscribe")
                angles.put(b'{"tm":{"sec":2,"nsec":5},"data":[0.5,-0.25]}')
                velocity.put(b'{"tm":{"sec":2,"nsec":5},"id":[],"vx":0.3,"vy":0.0,"w":0.1,"error":[]}')
                assert echo.process.wait(10) == 0
            finally:
                publisher_session.close()
            out = echo.process.stdout.read()
        code, _out, err = router.stop()
    assert code == 0, err
    assert json_lines(out) == [
        {"key": keys.sim_wheel_angles, "value": {"tm": {"sec": 2, "nsec": 5}, "data": [0.5, -0.25]}},
        {
            "key": keys.drive_target_velocity,
            "value": {"tm": {"sec": 2, "nsec": 5}, "id": [], "vx": 0.3, "vy": 0.0, "w": 0.1, "error": []},
        },
    ]


def test_echo_shows_unknown_keys_as_text_and_bad_payloads_with_the_reason(endpoint, session):
    keys = Keys("rh0")
    with InventProcess("echo", "**", "--count", "2", "--connect", endpoint) as echo:
        publisher = session.declare_publisher("demo/free_text")
        wait_until(lambda: publisher.matching_status.matching, 20, "invent echo to subscribe")
        publisher.put(b"hello")
        session.put(keys.odometry_pose, b'{"x": 1}')
        assert echo.process.wait(10) == 0
        lines = json_lines(echo.process.stdout.read())
    assert lines[0] == {"key": "demo/free_text", "value": "hello"}
    assert lines[1]["key"] == keys.odometry_pose and lines[1]["value"] == '{"x": 1}'
    assert "missing required field" in lines[1]["error"]


def test_call_prints_the_reply(endpoint, node):
    key = node.keys.method(MethodFamily.GUI, Method.START)
    node.queryable(key, lambda payload: {"echo": json.loads(payload) if payload else None})
    result = run_invent("call", key, '{"a": 1}', "--connect", endpoint)
    assert result.returncode == 0, result.stderr
    assert json_lines(result.stdout) == [{"key": key, "value": {"echo": {"a": 1}}}]


def test_call_exits_non_zero_on_reply_err(endpoint, node):
    key = node.keys.method(MethodFamily.GUI, Method.SET_PD_GAIN)

    def reject(_payload: bytes):
        raise BadInput("gains must be >= 0")

    node.queryable(key, reject)
    result = run_invent("call", key, "{}", "--connect", endpoint)
    assert result.returncode == 1
    assert "gains must be >= 0" in result.stderr
    assert node.status().bad_input.by_key[key].count == 1


def test_call_against_nothing_exits_non_zero_with_a_clear_message(endpoint):
    key = Keys("rh0").method(MethodFamily.GUI, Method.STOP)
    result = run_invent("call", key, "--timeout", "0.5", "--connect", endpoint)
    assert result.returncode == 1
    assert f"nothing answers on {key}" in result.stderr


def test_call_to_an_unreachable_router_names_the_connection_not_the_service():
    result = run_invent(
        "call", "invent/rh0/motor/status", "--timeout", "0.5", "--connect", f"tcp/127.0.0.1:{free_port()}"
    )
    assert result.returncode == 1
    assert "reached no router and no peer" in result.stderr and "is the service running" not in result.stderr


def test_call_on_a_wildcard_gets_every_status(endpoint, node):
    result = run_invent("call", "invent/*/*/status", "--connect", endpoint)
    assert result.returncode == 0, result.stderr
    [line] = json_lines(result.stdout)
    assert line["key"] == Keys("rh0").status(Service.MOTOR)


def test_status_lists_live_services_with_their_status(endpoint, node):
    result = run_invent("status", "--connect", endpoint)
    assert result.returncode == 0, result.stderr
    [line] = json_lines(result.stdout)
    assert (line["robot"], line["service"], line["alive"]) == ("rh0", "motor", True)
    assert line["status"]["state"] == "idle"
    assert line["status"]["bad_input"] == {"total": 0, "by_key": {}}


def test_status_with_nothing_alive_exits_non_zero(endpoint):
    result = run_invent("status", "--timeout", "0.3", "--connect", endpoint)
    assert result.returncode == 1
    assert "no service alive" in result.stderr


def test_router_stops_cleanly_on_sigint():
    with InventProcess("router", "--listen", f"tcp/127.0.0.1:{free_port()}") as router:
        lines = [router.process.stderr.readline()]
        if "listening on" not in lines[0]:  # with several CPUs, rt.partition's line comes first
            lines.append(router.process.stderr.readline())
        assert "listening on" in lines[-1], lines
        code, _out, err = router.stop()
    assert code == 0, err


def test_help_lists_every_subcommand():
    result = run_invent("--help")
    for command in ("router", "echo", "call", "status", "config"):
        assert command in result.stdout


def test_messages_published_by_a_node_reach_a_subscriber(endpoint, session, node):
    collector = Collector(session, node.keys.motor_torque, TimedDoubleSeq)
    publisher = node.publisher(node.keys.motor_torque)
    wait_until(lambda: publisher.matched, 10, "the collector")
    publisher.put(TimedDoubleSeq(Time(0, 1), [1.0, 2.0]))
    assert collector.get() == TimedDoubleSeq(Time(0, 1), [1.0, 2.0])


def test_call_help_says_how_to_send_a_target_by_hand():
    """Targets are data the motor takes by its stamp, not methods: `invent call --help` says so and
    names the tool that stamps them with simulation time."""
    result = run_invent("call", "--help")
    text = " ".join(result.stdout.split())
    assert result.returncode == 0
    assert "drive/target_velocity" in text and "stamped 0.0" in text and "invent drive --twist VX W" in text
