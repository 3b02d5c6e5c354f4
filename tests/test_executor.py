"""The executor's waits and channel inputs (order, wake-ups), and the opt-in low-latency transport."""

import json
import logging
import threading
import time

import pytest

from schemas import Keys, Service, Time, TimedDoubleSeq, encode
from services.runtime import executor as executor_module
from services.runtime.executor import EVENT_CAPACITY, Executor
from services.runtime.inputs import CHANNEL_CAPACITY, Delivery, LatestSample
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node
from services.runtime.session import LOW_LATENCY_VARIABLE, session_config
from tests.harness import Collector, open_peer, wait_until

KEYS = Keys("rh0")
WAKER_THREAD = "invent-waker"
LONG_WAKE_PERIOD_S = 60.0
"""Long enough that a wait ended within the test's 5 s was not ended by the waker's periodic look."""


def _sample(nsec: int) -> bytes:
    return encode(TimedDoubleSeq(Time(0, nsec), [0.0, 0.0]))


@pytest.fixture
def node(session):
    node = Node(session, KEYS, Service.MOTOR)
    yield node
    node.close()


@pytest.fixture
def remote(endpoint):
    """A second peer: its samples reach the node over the network, not by same-session delivery."""
    peer = open_peer(endpoint)
    yield peer
    peer.close()


def _spin_in_thread(node: Node, timeout: float | None, waiting_for=None) -> tuple[threading.Thread, list]:
    outcome: list = []

    def spin() -> None:
        started = time.monotonic()
        outcome.append((node.spin_once(timeout, waiting_for), time.monotonic() - started))

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    return thread, outcome


def _wait_blocked(node: Node) -> None:
    wait_until(lambda: node.executor.receiving, 5, "the thread to block in the channel receive")


def _put_while_blocked(node: Node, remote, key: str, nsec: int, timeout: float | None, waiting_for=None) -> None:
    """Publish one sample of ``key`` from the other peer once the node's thread waits in a receive
    (``spin_once(timeout, waiting_for)``), and check that it ended the wait at once."""
    publisher = remote.declare_publisher(key)
    wait_until(lambda: publisher.matching_status.matching, what=f"the node's subscriber of {key}")
    thread, outcome = _spin_in_thread(node, timeout, waiting_for)
    _wait_blocked(node)
    publisher.put(_sample(nsec))
    thread.join(5)
    publisher.undeclare()
    assert outcome and outcome[0][0] is True and outcome[0][1] < 5


def test_posted_events_come_first_then_channel_inputs_in_the_order_they_were_added(session, node):
    handled = []
    first, second = KEYS.sim_wheel_angles, KEYS.sim_body_pose
    node.subscribe(first, TimedDoubleSeq, lambda m: handled.append(("first", m.tm.nsec)), Delivery.EVERY, wakes=True)
    node.subscribe(second, TimedDoubleSeq, lambda m: handled.append(("second", m.tm.nsec)), Delivery.EVERY, wakes=True)
    session.put(second, _sample(1))  # same session: delivered into the channel inside put
    session.put(first, _sample(2))
    session.put(first, _sample(3))
    node.post(lambda: handled.append(("event", 0)))
    while node.spin_once(0):
        pass
    assert handled == [("event", 0), ("first", 2), ("first", 3), ("second", 1)]


def test_a_sample_from_another_process_ends_a_blocked_receive_at_once(node, remote):
    handled = []
    node.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, handled.append, Delivery.EVERY, wakes=True)
    _put_while_blocked(node, remote, KEYS.sim_wheel_angles, 7, 30.0)
    assert [m.tm.nsec for m in handled] == [7]


def test_a_posted_event_wakes_a_thread_blocked_in_a_channel_receive_at_once(node, monkeypatch):
    """At once, not at the waker's next periodic look: a lockstep tick waits on such events."""
    monkeypatch.setattr(executor_module, "WAKE_PERIOD_S", LONG_WAKE_PERIOD_S)
    node.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, lambda _m: None, Delivery.EVERY, wakes=True)
    events = []
    thread, outcome = _spin_in_thread(node, None)
    _wait_blocked(node)
    node.post(lambda: events.append(threading.current_thread()))
    thread.join(5)
    assert outcome and outcome[0][0] is True and outcome[0][1] < 5
    assert events == [thread]


def test_a_thread_waits_in_the_input_it_is_told_to_wait_for(node, remote, monkeypatch):
    monkeypatch.setattr(executor_module, "WAKE_PERIOD_S", LONG_WAKE_PERIOD_S)
    handled = []
    node.subscribe(
        KEYS.sim_wheel_angles,
        TimedDoubleSeq,
        lambda m: handled.append(("angles", m.tm.nsec)),
        Delivery.EVERY,
        wakes=True,
    )
    targets = node.subscribe(
        KEYS.drive_target_velocity, TimedDoubleSeq, lambda m: handled.append(("target", m.tm.nsec)), Delivery.NEWEST
    )
    _put_while_blocked(node, remote, KEYS.drive_target_velocity, 5, None, waiting_for=targets)
    assert handled == [("target", 5)]


def test_a_thread_told_to_wait_for_a_sampled_input_blocks_in_it_instead_of_polling(node, remote):
    """The drive between a lockstep tick's clock and its pose: nothing else counts meanwhile."""
    handled = []
    node.subscribe(
        KEYS.sim_wheel_angles, TimedDoubleSeq, lambda m: handled.append(("clock", m.tm.nsec)), Delivery.SAMPLED
    )
    pose = node.subscribe(
        KEYS.odometry_pose, TimedDoubleSeq, lambda m: handled.append(("pose", m.tm.nsec)), Delivery.SAMPLED
    )
    _put_while_blocked(node, remote, KEYS.odometry_pose, 9, 30.0, waiting_for=pose)
    assert handled == [("pose", 9)]


def test_a_sampled_input_never_hands_over_a_sample_older_than_one_it_handed_over(session):
    """A blocking receive takes the sample out of the ring; a newer one may follow before the take."""
    handled = []
    key = KEYS.sim_wheel_angles
    sampled = LatestSample(session, key, lambda payload, _attachment: handled.append(payload))
    session.put(key, _sample(1))
    received = sampled.receive()
    session.put(key, _sample(2))
    sampled.put_back(received)
    assert sampled.take() is True and handled == [_sample(2)], "the newer sample, and only it"
    session.put(key, _sample(3))
    sampled.put_back(sampled.receive())
    assert sampled.take() is True and handled == [_sample(2), _sample(3)], "nothing newer: the one received"
    assert sampled.take() is False
    sampled.undeclare()


def test_a_wake_never_pushes_the_newest_sample_out_of_a_newest_input(session, node):
    handled = []
    targets = node.subscribe(
        KEYS.drive_target_velocity, TimedDoubleSeq, lambda m: handled.append(m.tm.nsec), Delivery.NEWEST
    )
    session.put(KEYS.drive_target_velocity, _sample(3))
    targets.wake()  # what the waker sends when it ends a wait just as the sample arrives
    while node.spin_once(0):
        pass
    assert handled == [3]


class _DescheduledSample(LatestSample):
    """A newest-only input whose thread, blocked in its receive, does not run again for a while (a
    loaded machine), and which counts the wake samples it is sent meanwhile."""

    DESCHEDULED_S = 0.2
    """Twenty of the waker's periods."""

    def __init__(self, *args) -> None:
        super().__init__(*args)
        self.wakes = 0

    def receive(self):
        time.sleep(self.DESCHEDULED_S)  # the thread not running, not a wait for a condition
        return super().receive()

    def wake(self) -> None:
        self.wakes += 1
        super().wake()


def test_a_thread_kept_from_running_in_its_receive_is_woken_once_and_its_newest_sample_survives(session):
    """Seen under load: the waker sent a wake every 10 ms to a thread that had not run yet; two
    wakes filled the newest-only ring and pushed out the lockstep tick's clock sample."""
    handled = []
    executor = Executor()
    clock = _DescheduledSample(session, KEYS.sim_wheel_angles, lambda payload, _attachment: handled.append(payload))
    executor.add_sampled(clock)
    thread = threading.Thread(target=executor.spin_once, args=(0.05, clock), daemon=True)
    thread.start()
    wait_until(lambda: clock.wakes >= 1, 5, "the waker to end the wait")
    session.put(KEYS.sim_wheel_angles, _sample(7))
    thread.join(5)
    while executor.spin_once(0):
        pass
    assert handled == [_sample(7)], "the newest sample survived the wakes"
    assert clock.wakes == 1
    executor.remove_input(clock)
    clock.undeclare()


def test_a_blocked_receive_ends_when_its_timeout_is_over_and_the_wake_is_seen_by_no_one(session, node, remote):
    handled = []
    key = KEYS.sim_wheel_angles
    node.subscribe(key, TimedDoubleSeq, handled.append, Delivery.EVERY, wakes=True)
    sampled = LatestSample(session, key, lambda payload, _attachment: handled.append(payload))
    elsewhere = Collector(remote, key)
    thread, outcome = _spin_in_thread(node, 0.3)
    thread.join(5)
    assert outcome and outcome[0][0] is False and 0.3 <= outcome[0][1] < 2.0
    assert not node.spin_once(0), "the wake sample is not an input"
    assert sampled.take() is False, "nor a sample for a sampled input of the same session"
    assert handled == [] and node.status().bad_input.total == 0
    assert elsewhere.drain() == [], "it never leaves the session"
    elsewhere.close()
    sampled.undeclare()


def test_closing_the_node_stops_the_waker(session):
    def wakers() -> int:
        return sum(thread.name == WAKER_THREAD for thread in threading.enumerate())

    before = wakers()
    node = Node(session, KEYS, Service.SIM)
    node.subscribe(KEYS.motor_torque, TimedDoubleSeq, lambda _m: None, Delivery.EVERY, wakes=True)
    assert wakers() == before + 1
    node.close()
    assert wakers() == before


def test_a_short_wait_right_after_an_event_returns_every_time():
    """``queue.SimpleQueue.get(timeout)`` on CPython 3.11 could wait forever in exactly this pattern."""
    executor = Executor()
    done = []

    def cycles() -> None:
        for _ in range(3000):
            executor.post(lambda _: None, None)
            executor.spin_once(None)
            executor.spin_once(2e-6)
        done.append(True)

    thread = threading.Thread(target=cycles, daemon=True)
    thread.start()
    thread.join(30)
    assert done, "spin_once(timeout) did not return"


def test_the_low_latency_transport_is_opt_in(monkeypatch):
    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    monkeypatch.delenv(LOW_LATENCY_VARIABLE, raising=False)
    assert json.loads(str(session_config()))["transport"]["unicast"]["lowlatency"] is False
    monkeypatch.setenv(LOW_LATENCY_VARIABLE, "1")
    for mode in ("peer", "router"):
        config = json.loads(str(session_config(mode=mode)))
        assert config["transport"]["unicast"]["lowlatency"] is True
        assert config["transport"]["unicast"]["qos"]["enabled"] is False
        assert config["scouting"]["gossip"]["autoconnect_strategy"]["peer"]["to_peer"] == "greater-zid"


def test_a_sampled_input_hands_over_only_the_newest_sample_and_an_idle_executor_waits_for_it(session, node, remote):
    handled = []
    node.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, handled.append, Delivery.SAMPLED)
    session.put(KEYS.sim_wheel_angles, _sample(1))  # same session: both are in the ring before the look
    session.put(KEYS.sim_wheel_angles, _sample(2))
    assert node.spin_once(0) is True
    assert [m.tm.nsec for m in handled] == [2], "only the newest sample, not a backlog"
    publisher = remote.declare_publisher(KEYS.sim_wheel_angles)
    wait_until(lambda: publisher.matching_status.matching, what="the node's sampled subscriber")
    thread, outcome = _spin_in_thread(node, 30.0)
    publisher.put(_sample(3))
    thread.join(5)
    assert outcome and outcome[0][0] is True and outcome[0][1] < 5, "an idle executor looks again within its poll"
    assert [m.tm.nsec for m in handled] == [2, 3]
    publisher.undeclare()


def test_a_busy_executor_still_looks_at_its_sampled_inputs(session, node):
    """A shared executor (``invent up --composed``) never runs dry: samples keep coming."""
    order = []
    backlog = CHANNEL_CAPACITY
    work_s = 50e-6
    """Per channel sample: the backlog takes ten times the sampling poll to work off."""

    def on_channel(_message: TimedDoubleSeq) -> None:
        order.append("channel")
        if len(order) == 10:
            session.put(KEYS.sim_wheel_angles, _sample(0))
        busy_until = time.perf_counter() + work_s
        while time.perf_counter() < busy_until:
            pass

    node.subscribe(KEYS.motor_wheel_angles, TimedDoubleSeq, on_channel, Delivery.EVERY, wakes=True)
    node.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, lambda _m: order.append("sampled"), Delivery.SAMPLED)
    for index in range(backlog):
        session.put(KEYS.motor_wheel_angles, _sample(index))
    while node.spin_once(0):
        pass
    assert order.count("channel") == backlog and order.count("sampled") == 1
    assert order.index("sampled") < backlog, "handled while the channel still had samples waiting"


def test_a_flooded_channel_input_keeps_only_its_newest_samples(session, node):
    handled = []
    node.subscribe(KEYS.motor_wheel_angles, TimedDoubleSeq, handled.append, Delivery.EVERY, wakes=True)
    flood = 3 * CHANNEL_CAPACITY
    for index in range(flood):
        session.put(KEYS.motor_wheel_angles, _sample(index))
    while node.spin_once(0):
        pass
    assert [m.tm.nsec for m in handled] == list(range(flood - CHANNEL_CAPACITY, flood))


def test_a_newest_input_holds_one_sample_and_comes_after_the_channel_inputs(session, node):
    order = []
    node.subscribe(
        KEYS.motor_wheel_angles,
        TimedDoubleSeq,
        lambda m: order.append(("angles", m.tm.nsec)),
        Delivery.EVERY,
        wakes=True,
    )
    node.subscribe(
        KEYS.drive_target_velocity, TimedDoubleSeq, lambda m: order.append(("target", m.tm.nsec)), Delivery.NEWEST
    )
    for index in range(1000):
        session.put(KEYS.drive_target_velocity, _sample(index))
    session.put(KEYS.motor_wheel_angles, _sample(7))
    while node.spin_once(0):
        pass
    assert order == [("angles", 7), ("target", 999)]


def test_the_event_queue_is_bounded_and_counts_what_it_drops():
    executor = Executor()
    handled = []
    for index in range(EVENT_CAPACITY + 10):
        executor.post(handled.append, index)
    while executor.spin_once(0):
        pass
    assert handled == list(range(EVENT_CAPACITY))
    assert executor.dropped_events == 10


def test_rate_limited_log_says_one_line_per_key_per_interval_and_counts_the_rest(caplog):
    logger = logging.getLogger("invent.test-rate-limited")
    limited = RateLimitedLog(logger, interval_s=3600.0)
    with caplog.at_level(logging.WARNING, logger=logger.name):
        for _ in range(1000):
            limited("a", logging.WARNING, "key %s", "a")
        limited("b", logging.WARNING, "key %s", "b")
    assert [record.getMessage() for record in caplog.records] == ["key a", "key b"]
    limited._last["a"] = float("-inf")  # the interval is over
    with caplog.at_level(logging.WARNING, logger=logger.name):
        limited("a", logging.WARNING, "key %s", "a")
    assert caplog.records[-1].getMessage() == "key a (999 more since the last line)"
