"""The service runtime: handoff to the service thread, the bad-input policy, liveliness, config."""

import ctypes
import ctypes.util
import json
import logging
import signal
import subprocess
import sys
import threading

import pytest

from schemas import BadInput, Keys, Service, Time, TimedDoubleSeq
from services.runtime.inputs import Delivery
from services.runtime.node import Node
from services.runtime.session import DEFAULT_ENDPOINT, LOOPBACK_LISTEN, has_match, session_config, stop_on_signals
from tests.harness import REPO, call, free_port, peer_session, refused, run_invent, wait_until
from tests.status_samples import StateStatus


@pytest.fixture
def node(session):
    node = Node(session, Keys("rh0"), Service.ODOMETRY)
    yield node
    node.close()


def _feeding(session, node, handler):
    """A publisher whose samples reach ``handler`` through ``node`` (queued), once they match."""
    node.subscribe(node.keys.motor_wheel_angles, TimedDoubleSeq, handler, Delivery.QUEUED)
    publisher = session.declare_publisher(node.keys.motor_wheel_angles)
    wait_until(lambda: has_match(publisher))
    return publisher


def _spin_until(node, predicate, timeout=10.0):
    """Handle the node's events on this thread until ``predicate()`` holds."""

    def spun_and_holds():
        node.spin_once(0.01)
        return predicate()

    wait_until(spun_and_holds, timeout)


def test_handlers_run_on_the_service_thread_not_in_zenoh_callbacks(session, node):
    threads = []
    publisher = _feeding(session, node, lambda _m: threads.append(threading.current_thread()))
    publisher.put(b'{"tm":{"sec":0,"nsec":1},"data":[0.0,0.0]}')
    _spin_until(node, lambda: threads)
    assert threads == [threading.main_thread()]


def test_bad_input_is_dropped_counted_and_logged_once_per_interval(session, node, caplog):
    received = []
    key = node.keys.motor_wheel_angles
    publisher = _feeding(session, node, received.append)
    with caplog.at_level(logging.WARNING, logger="invent"):
        publisher.put(b"garbage")
        publisher.put(b'{"tm":{"sec":0,"nsec":1},"data":[1e999]}')
        publisher.put(b'{"tm":{"sec":0,"nsec":2},"data":[1.0]}')
        _spin_until(node, lambda: received)
    assert received == [TimedDoubleSeq(Time(0, 2), [1.0])]
    counts = node.status().bad_input
    assert counts.total == 2
    assert counts.by_key[key].count == 2
    assert "out of range" in counts.by_key[key].last_reason
    lines = [r.getMessage() for r in caplog.records if "bad input" in r.getMessage()]
    assert len(lines) == 1
    assert key in lines[0] and "not JSON" in lines[0]


def test_a_handler_raising_bad_input_is_counted_and_the_node_goes_on(session, node):
    seen = []

    def handler(message: TimedDoubleSeq) -> None:
        if message.tm.nsec == 1:
            raise BadInput("dt <= 0")
        seen.append(message)

    key = node.keys.motor_wheel_angles
    publisher = _feeding(session, node, handler)
    publisher.put(b'{"tm":{"sec":0,"nsec":1},"data":[]}')
    publisher.put(b'{"tm":{"sec":0,"nsec":2},"data":[]}')
    _spin_until(node, lambda: seen)
    assert node.bad_inputs.by_key[key].last_reason == "dt <= 0"


def test_a_bug_in_a_handler_is_logged_counted_and_not_fatal(session, node):
    seen = []

    def handler(message: TimedDoubleSeq) -> None:
        seen.append(1 / message.data[0])

    publisher = _feeding(session, node, handler)
    publisher.put(b'{"tm":{"sec":0,"nsec":1},"data":[0.0]}')
    publisher.put(b'{"tm":{"sec":0,"nsec":2},"data":[4.0]}')
    _spin_until(node, lambda: seen)
    assert seen == [0.25]
    assert node.status().internal_errors == 1


def test_status_and_queryables_answer_from_the_service_thread(session, node):
    node.set_status(lambda: StateStatus(state="running"))
    stop = threading.Event()
    spinner = threading.Thread(target=node.serve, args=(stop, lambda: False))
    spinner.start()
    try:
        ok, status = call(session, node.keys.status(Service.ODOMETRY))
        assert ok and status["state"] == "running" and status["service"] == "odometry"

        def reject(payload: bytes):
            raise BadInput(f"bad argument {payload.decode()}")

        key = node.keys.prefix + "/odometry/reset"
        node.queryable(key, reject)
        ok, error = call(session, key, "x")
        assert not ok and error == {"error": "bad argument x"}
    finally:
        stop.set()
        spinner.join()


def test_close_withdraws_the_liveliness_token(session):
    keys = Keys("rh5")
    events = []
    subscriber = session.liveliness().declare_subscriber(keys.alive(Service.SIM), lambda s: events.append(str(s.kind)))
    node = Node(session, keys, Service.SIM)
    wait_until(lambda: events, what="the token")
    node.close()
    wait_until(lambda: len(events) == 2, what="the token to be withdrawn")
    assert events == ["SampleKind.PUT", "SampleKind.DELETE"]
    subscriber.undeclare()


def test_session_config_defaults_to_peer_with_explicit_endpoint(monkeypatch):
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    config = json.loads(str(session_config()))
    assert config["mode"] == "peer"
    assert config["scouting"]["multicast"]["enabled"] is False
    assert config["connect"]["endpoints"] == [DEFAULT_ENDPOINT]
    router = json.loads(str(session_config(mode="router")))
    assert router["listen"]["endpoints"] == [DEFAULT_ENDPOINT]


def test_session_config_flags_override_zenoh_config_file(tmp_path, monkeypatch):
    path = tmp_path / "zenoh.json5"
    path.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:1111"] } }')
    monkeypatch.setenv("ZENOH_CONFIG", str(path))
    from_file = json.loads(str(session_config()))
    assert from_file["mode"] == "client" and from_file["connect"]["endpoints"] == ["tcp/127.0.0.1:1111"]
    overridden = json.loads(str(session_config(connect=["tcp/127.0.0.1:2222"], listen=["tcp/127.0.0.1:3333"])))
    assert overridden["connect"]["endpoints"] == ["tcp/127.0.0.1:2222"]
    assert overridden["listen"]["endpoints"] == ["tcp/127.0.0.1:3333"]


def test_watch_reports_a_neighbour_that_comes_and_goes_and_comes_back(session, node):
    changes = []
    node.watch(Service.SIM, changes.append)
    for expected in ([True], [True, False], [True, False, True]):
        if len(expected) % 2:
            neighbour = Node(session, node.keys, Service.SIM)
        else:
            neighbour.close()
        _spin_until(node, lambda expected=expected: changes == expected)
    neighbour.close()


def test_nodes_sharing_an_executor_are_handled_by_one_thread_in_order(session):
    from services.runtime.executor import Executor

    executor = Executor()
    keys = Keys("rh0")
    first = Node(session, keys, Service.MOTOR, executor=executor)
    second = Node(session, keys, Service.ODOMETRY, executor=executor)
    order = []
    first.post(lambda: order.append("first"))
    second.post(lambda: order.append("second"))
    assert second.spin_once(0) and first.spin_once(0)
    assert order == ["first", "second"]
    first.close()
    second.close()


def test_a_peer_listens_on_loopback_unless_told(monkeypatch, tmp_path):
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    assert json.loads(str(session_config()))["listen"]["endpoints"] == [LOOPBACK_LISTEN]
    more = json.loads(str(session_config(listen=["tcp/0.0.0.0:7000"])))
    assert more["listen"]["endpoints"] == [LOOPBACK_LISTEN, "tcp/0.0.0.0:7000"]
    peer_file = tmp_path / "peer.json5"
    peer_file.write_text('{ mode: "peer" }')
    assert json.loads(str(session_config(file=str(peer_file))))["listen"]["endpoints"] == [LOOPBACK_LISTEN]
    own_listen = tmp_path / "own.json5"
    own_listen.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7001"] } }')
    assert json.loads(str(session_config(file=str(own_listen))))["listen"]["endpoints"] == ["tcp/127.0.0.1:7001"]
    client_file = tmp_path / "client.json5"
    client_file.write_text('{ mode: "client" }')
    assert "client" not in json.loads(str(session_config(file=str(client_file))))["listen"]["endpoints"]


def test_an_unreadable_zenoh_config_exits_2_naming_the_file(tmp_path, capsys):
    path = tmp_path / "broken.json5"
    path.write_text("{ mode: ")
    code, _out, err = refused(capsys, "status", "--zenoh-config", str(path))
    assert code == 2 and str(path) in err, err


def test_a_session_that_cannot_connect_exits_1_naming_the_endpoint(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    path = tmp_path / "client.json5"
    path.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint], "timeout_ms": 300}}))
    result = run_invent("call", "invent/rh0/motor/status", "--zenoh-config", str(path))
    assert result.returncode == 1
    assert f"cannot open a zenoh session connecting to {endpoint}" in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_a_second_signal_while_the_first_sets_the_stop_event_does_not_deadlock():
    """SIGTERM then SIGINT: Python may run the second handler inside the first one's Event.set,
    which holds the event's lock. The second must return, not wait for that lock for ever."""
    previous = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        stop = stop_on_signals()
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler)
        set_event = stop.set

        def set_while_a_second_signal_comes() -> None:
            with stop._cond:  # the first handler is inside Event.set, holding the event's lock
                handler(signal.SIGINT, None)
            set_event()

        stop.set = set_while_a_second_signal_comes  # type: ignore[method-assign]
        handled = threading.Thread(target=handler, args=(signal.SIGTERM, None), daemon=True)
        handled.start()
        handled.join(timeout=5.0)
        assert not handled.is_alive(), "the second signal's handler waited for the first one's lock"
        assert stop.is_set()
    finally:
        for number, handler_before in previous.items():
            signal.signal(number, handler_before)


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks")
    ]


def _malloc_in_use() -> int:
    """Bytes the C allocator has handed out and not had back (glibc's mallinfo2): zenoh's buffers among them."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    if not hasattr(libc, "mallinfo2"):
        pytest.skip("the C library has no mallinfo2 (glibc 2.33 or later)")
    libc.mallinfo2.restype = _MallInfo2
    return libc.mallinfo2().uordblks


def test_a_backlog_of_queued_samples_holds_their_bytes_not_the_batches_they_arrived_in(endpoint, session, node):
    """A zenoh sample keeps the whole receive batch it arrived in (about 50 kB, for a 100-byte
    message sent alone): 500 of them queued while the service thread was busy held 25 MB, which the
    allocator kept once freed (the realtime sim's memory grew so in the soak)."""
    received = []
    node.subscribe(node.keys.motor_wheel_angles, TimedDoubleSeq, received.append, Delivery.QUEUED)
    backlog = 500
    with peer_session(endpoint) as other:
        publisher = other.declare_publisher(node.keys.motor_wheel_angles)
        wait_until(lambda: has_match(publisher))
        before = _malloc_in_use()
        for index in range(backlog):
            publisher.put(f'{{"tm":{{"sec":0,"nsec":{index + 1}}},"data":[0.0,0.0]}}'.encode())
            threading.Event().wait(0.0005)  # each sample in a batch of its own, as a 1 kHz stream sends them
        wait_until(lambda: node.executor.queued == backlog)
        held = _malloc_in_use() - before
    _spin_until(node, lambda: len(received) == backlog)
    assert held < 5_000_000, f"{held / 1e6:.1f} MB held by {backlog} queued samples"


STUCK_IN_SHUTDOWN = """
import sys, threading
from services.runtime.session import stop_on_signals

def stuck_in_shutdown(never: threading.Event) -> None:
    never.wait()

stop = stop_on_signals(shutdown_watchdog_s=1.0)
print("ready", flush=True)
stop.wait()
stuck_in_shutdown(threading.Event())
"""


def test_a_process_stuck_in_its_shutdown_prints_where_and_exits_1_after_the_watchdog():
    """A service whose shutdown hangs (seen once: a view that never exited after SIGINT) must not
    wait to be killed silently: the watchdog prints every thread's stack, naming the stuck frame,
    and ends the process with exit 1."""
    process = subprocess.Popen(
        [sys.executable, "-c", STUCK_IN_SHUTDOWN], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert process.stdout is not None and process.stdout.readline() == "ready\n"
        process.send_signal(signal.SIGTERM)
        _out, err = process.communicate(timeout=15)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 1, err
    assert "Timeout (0:00:01)!" in err and "stuck_in_shutdown" in err, err
