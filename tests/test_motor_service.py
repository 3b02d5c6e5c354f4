"""``invent motor`` in its own process over real zenoh, checked against MotorCore as a mirror
(tests/test_motor_service_runs.py: the tests that start motors of their own).

One process serves most of the module (its start is the slow part). Each test begins with
:meth:`MotorLink.reset`, which brings the service to a known state (clear, start, default
gains, a fresh target) and builds a mirror core in step with it, so each test asserts its
own behaviour whatever ran before it. Samples are sent one at a time and each waits for its
torque, and each target or method waits for the service to confirm it, so the order of events
is the same on both sides.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import msgspec
import pytest
import zenoh

from schemas.codec import ENCODING, decode, encode
from schemas.keys import Keys, Service
from schemas.messages import PDGains, Time, TimedDoubleSeq, TimedVelocity
from schemas.topics import Method, MethodFamily
from services.clock.lockstep import encode_mark
from services.config import load_config
from services.motor.core import MotorCore
from tests.harness import (
    Collector,
    InventProcess,
    call,
    free_port,
    open_peer,
    open_router,
    status_reply,
    wait_alive,
    wait_until,
)

ROBOT = "mot1"
OVERRIDES: dict[str, Any] = {
    "robot.left_wheel_id": 1,
    "robot.right_wheel_id": 2,
    "robot.radius_of_right_wheel": 0.12,
    "motor.simulated_offset_y": 0.045795,
    "motor.simulated_offset_angle": 1.5708,
    # Limits far beyond the speeds sent here: the seed's law, which a fresh mirror follows from
    # whatever command the service had (the default limits ramp from the previous command).
    "motor.max_vx": 100.0,
    "motor.max_ax": 1e9,
    "motor.max_w": 100.0,
    "motor.max_aw": 1e9,
}
"""Non-default wheel ids (joint 0 is no wheel), unequal radii and the seed's RH0 offsets."""
CONFIG = load_config(overrides={"robot.name": ROBOT, **OVERRIDES})
DEFAULT_GAINS = PDGains(CONFIG.motor.p_gain_l, CONFIG.motor.p_gain_r, CONFIG.motor.d_gain_l, CONFIG.motor.d_gain_r)
STEP_NS = 1_000_000
RESET_GAP_NS = 200 * STEP_NS
TRACE_FIELDS = {"tm", "state", "angles", "q", "dq", "target", "command", "dq_ref", "q_ref", "gains", "torque"}
"""The fields of a --trace line, as docs/motor.md lists them."""
FIRST_TM = Time(10, 0)


def set_flags(overrides: dict[str, Any]) -> list[str]:
    return [flag for key, value in overrides.items() for flag in ("--set", f"{key}={value}")]


def wheels(q_left: float, q_right: float, other: float = 0.25) -> list[float]:
    """A wheel-angle vector in this robot's layout: [other joint, left, right]."""
    return [other, q_left, q_right]


class MotorLink:
    """The test's side of the service: raw publishers, collectors and the mirror core."""

    def __init__(self, session: zenoh.Session, keys: Keys, config=CONFIG) -> None:
        self.session = session
        self.keys = keys
        self.config = config
        self.torques = Collector(session, keys.motor_torque, TimedDoubleSeq)
        self.passed_on = Collector(session, keys.motor_wheel_angles, TimedDoubleSeq)
        self.pose_gui = Collector(session, keys.motor_sim_pose_gui, TimedDoubleSeq)
        self.pose_localization = Collector(session, keys.motor_sim_pose_localization, TimedDoubleSeq)
        self.outputs: list[tuple[str, Time]] = []
        """(key, tm) of every motor/torque and motor/wheel_angles sample, in arrival order."""
        self._outputs = session.declare_subscriber(
            f"{keys.prefix}/{Service.MOTOR}/*",
            lambda sample: self.outputs.append(
                (str(sample.key_expr), decode(TimedDoubleSeq, sample.payload.to_bytes()).tm)
            ),
        )
        encoding = zenoh.Encoding(ENCODING)
        self.publishers = {
            key: session.declare_publisher(key, encoding=encoding)
            for key in (keys.sim_wheel_angles, keys.sim_body_pose, keys.drive_target_velocity)
        }
        self.time_ns = FIRST_TM.to_nanoseconds()
        self.mirror = MotorCore(config.robot, config.motor)

    def wait_matched(self) -> None:
        for key, publisher in self.publishers.items():
            wait_until(lambda p=publisher: p.matching_status.matching, what=f"a subscriber on {key}")

    def put(self, key: str, payload: bytes | str) -> None:
        self.publishers[key].put(payload)

    def status(self) -> dict[str, Any]:
        return status_reply(self.session, self.keys, Service.MOTOR)

    def counter(self, name: str) -> int:
        return self.status()["counters"][name]

    def bad_input_count(self, key: str) -> int:
        return self.status()["bad_input"]["by_key"].get(key, {}).get("count", 0)

    def method(
        self, method: Method, payload: bytes | str | None = None, family: MethodFamily = MethodFamily.GUI
    ) -> tuple[bool, Any]:
        return call(self.session, self.keys.method(family, method), payload)

    def invoke(self, method: Method, gains: PDGains | None = None, family: MethodFamily = MethodFamily.GUI) -> dict:
        """Call a Motor method on the service and the mirror; return the service's status reply."""
        ok, reply = self.method(method, encode(gains) if gains else None, family)
        assert ok, reply
        if method is Method.SET_PD_GAIN:
            self.mirror.set_pd_gain(gains)
        else:
            getattr(self.mirror, method)()
        assert reply["state"] == self.mirror.state
        return reply

    def target(self, vx: float, w: float) -> None:
        """Publish a target velocity and wait until the service accepted or ignored it."""
        counters = self.status()["counters"]
        seen = counters["target_velocity_samples"] + counters["targets_ignored"]
        stamp = Time.from_nanoseconds(max(self.time_ns, 0))
        self.put(self.keys.drive_target_velocity, encode(TimedVelocity(stamp, [], vx, 0.0, w, [])))
        wait_until(
            lambda: sum(self.status()["counters"][k] for k in ("target_velocity_samples", "targets_ignored")) > seen,
            what="the target velocity to be handled",
        )
        self.mirror.set_target(vx, w)

    def cycle(self, angles: list[float], dt_ns: int = STEP_NS) -> tuple[list[float], list[float]]:
        """Send one wheel-angle sample; return (torque the service published, the mirror's torque).

        Also checks the protocol: the torque carries the sample's tm and is followed by
        motor/wheel_angles, the input unchanged with the same tm.
        """
        self.time_ns += dt_ns
        sample = TimedDoubleSeq(Time.from_nanoseconds(self.time_ns), angles)
        self.put(self.keys.sim_wheel_angles, encode(sample))
        torque = self.torques.get()
        assert torque.tm == sample.tm
        assert self.passed_on.get() == sample
        return torque.data, self.mirror.step(self.time_ns, angles)

    def reset(self, vx: float, w: float) -> None:
        """Bring the service to a known running state and start a mirror in step with it."""
        for method in (Method.CLEAR, Method.START):
            assert self.method(method)[0]
        assert self.method(Method.SET_PD_GAIN, encode(DEFAULT_GAINS))[0]
        self.torques.drain()
        self.passed_on.drain()
        self.mirror = MotorCore(self.config.robot, self.config.motor)
        # The mirror's first sample, the service's next one: after a gap long enough that
        # returning the wheels to 0 is a plausible speed (input.max_wheel_speed).
        self.cycle(wheels(0.0, 0.0), RESET_GAP_NS)
        self.target(vx, w)

    def close(self) -> None:
        self._outputs.undeclare()
        for collector in (self.torques, self.passed_on, self.pose_gui, self.pose_localization):
            collector.close()
        for publisher in self.publishers.values():
            publisher.undeclare()


@pytest.fixture(scope="module")
def link() -> Iterator[MotorLink]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    session = open_peer(endpoint)
    keys = Keys(ROBOT)
    motor_link = MotorLink(session, keys)
    try:
        with InventProcess("motor", "--connect", endpoint, "--robot", ROBOT, *set_flags(OVERRIDES)) as motor:
            wait_alive(session, keys.alive(Service.MOTOR))
            motor_link.wait_matched()
            yield motor_link
            code, _out, err = motor.stop()
            assert code == 0, err
    finally:
        motor_link.close()
        session.close()
        router.close()


def moving(k: int) -> list[float]:
    """Wheels turning at roughly 5 and 4 rad/s with some wobble, sample k."""
    return wheels(0.005 * k + 0.0003 * math.sin(k), 0.004 * k - 0.0002 * math.cos(k), other=0.1 * k)


def test_torques_equal_the_core_math_for_a_sequence(link):
    link.reset(vx=0.4, w=0.3)
    first_ns = link.time_ns + 1
    steps = [STEP_NS, 2 * STEP_NS, STEP_NS // 2] * 6
    sent = []
    for k, dt_ns in enumerate(steps, start=1):
        torques, expected = link.cycle(moving(k), dt_ns)
        sent.append(Time.from_nanoseconds(link.time_ns))
        assert len(torques) == 3 and torques[0] == 0.0
        assert torques == expected
        assert torques[1] != 0.0 and torques[2] != 0.0

    def outputs_of_this_sequence() -> list[tuple[str, Time]]:
        return [(key, tm) for key, tm in list(link.outputs) if tm.to_nanoseconds() >= first_ns]

    wait_until(lambda: len(outputs_of_this_sequence()) == 2 * len(steps), what="every output sample")
    torque_then_angles = [(key, tm) for tm in sent for key in (link.keys.motor_torque, link.keys.motor_wheel_angles)]
    assert outputs_of_this_sequence() == torque_then_angles


def test_stop_brakes_and_ignores_new_targets_until_clear(link):
    link.reset(vx=0.5, w=0.0)
    for k in range(1, 4):
        link.cycle(moving(k))
    assert link.invoke(Method.STOP, family=MethodFamily.BUMP)["state"] == "stopped"
    link.target(1.0, 0.5)
    status = link.status()
    assert status["target"] == {"vx": 0.0, "w": 0.0}
    assert status["counters"]["targets_ignored"] >= 1
    for k in range(4, 8):
        torques, expected = link.cycle(moving(k))
        assert torques == expected
        assert torques[1] < 0 and torques[2] < 0, "wheels turning forward are braked"
    assert link.invoke(Method.CLEAR)["state"] == "running"
    torques, expected = link.cycle(moving(8))
    assert torques == expected and link.mirror.command == (0.0, 0.0), "clear does not resume the old target"
    link.target(0.2, 0.0)
    torques, expected = link.cycle(moving(9))
    assert torques == expected and link.mirror.command == (0.2, 0.0)


def test_finish_coasts_until_start(link):
    link.reset(vx=0.5, w=0.2)
    link.cycle(moving(1))
    assert link.invoke(Method.FINISH)["state"] == "finished"
    for k in range(2, 6):
        torques, _ = link.cycle(moving(k))
        assert torques == [0.0, 0.0, 0.0]
    link.target(0.3, 0.0)
    assert link.cycle(moving(6))[0] == [0.0, 0.0, 0.0]
    assert link.invoke(Method.START)["state"] == "running"
    torques, expected = link.cycle(moving(7))
    assert torques == expected and torques != [0.0, 0.0, 0.0]


def test_set_pd_gain_changes_the_next_torque(link):
    link.reset(vx=0.5, w=0.0)
    link.cycle(moving(1))
    with_old_gains = MotorCore(CONFIG.robot, CONFIG.motor)
    with_old_gains.set_target(0.5, 0.0)
    with_old_gains.step(link.time_ns, moving(1))
    new_gains = PDGains(p_gain_l=1.0, p_gain_r=2.0, d_gain_l=3.0, d_gain_r=4.0)
    assert link.invoke(Method.SET_PD_GAIN, new_gains)["gains"] == msgspec.to_builtins(new_gains)
    torques, expected = link.cycle(moving(2))
    assert torques == expected
    assert torques != with_old_gains.step(link.time_ns, moving(2))


def bad_wheel_samples(link: MotorLink) -> list[bytes]:
    last = Time.from_nanoseconds(link.time_ns)
    later = Time.from_nanoseconds(link.time_ns + 5 * STEP_NS)
    return [
        b"not json",
        b'{"tm": {"sec": 1, "nsec": 0}}',
        encode(TimedDoubleSeq(later, [0.0, 0.0])),  # wheel id 2 out of range
        encode(TimedDoubleSeq(last, wheels(9.0, 9.0))),  # dt = 0
        encode(TimedDoubleSeq(Time(0, 0), wheels(9.0, 9.0))),  # dt < 0
    ]


def test_bad_payload_on_every_input_key_is_dropped_and_counted(link):
    link.reset(vx=0.3, w=0.1)
    keys = link.keys
    bad = {
        keys.sim_wheel_angles: bad_wheel_samples(link),
        keys.sim_body_pose: [
            b"[1, 2",
            encode(TimedDoubleSeq(FIRST_TM, [0.0] * 11)),
            b'{"tm": {"sec": -1, "nsec": 0}, "data": []}',
        ],
        keys.drive_target_velocity: [
            b"{}",
            b'{"tm": {"sec": 0, "nsec": 0}, "id": [], "vx": "fast", "vy": 0, "w": 0, "error": []}',
        ],
    }
    # One at a time: the target is a newest-only input, where a sample overwritten before it is
    # taken is never seen.
    for key, payloads in bad.items():
        for count, payload in enumerate(payloads, start=1):
            link.put(key, payload)
            wait_until(lambda k=key, n=count: link.bad_input_count(k) == n, what=f"bad input counted on {key}")
    status = link.status()
    assert status["bad_input"]["total"] == sum(len(p) for p in bad.values())
    assert status["target"] == {"vx": 0.3, "w": 0.1}, "a bad target changes nothing"
    assert link.torques.drain() == [], "a dropped wheel-angle sample gets no torque"
    assert link.pose_gui.drain() == []
    torques, expected = link.cycle(moving(1))
    assert torques == expected
    identity_pose = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    link.put(keys.sim_body_pose, encode(TimedDoubleSeq(Time.from_nanoseconds(link.time_ns), identity_pose)))
    for collector in (link.pose_gui, link.pose_localization):
        assert collector.get().data == link.mirror.sim_pose(identity_pose), "still converting body poses"


def bad_method_payloads(method: Method) -> list[bytes]:
    if method is Method.SET_PD_GAIN:
        return [b"", b'{"p_gain_l": -1, "p_gain_r": 1, "d_gain_l": 1, "d_gain_r": 1}', b'{"p_gain_l": 1}']
    return [b"not json", b'{"unexpected": 1}']


def test_bad_payload_on_every_method_gets_reply_err_and_changes_nothing(link):
    link.reset(vx=0.3, w=0.0)
    before = link.status()
    expected_counts = {}
    for family in MethodFamily:
        for method in Method:
            payloads = bad_method_payloads(method)
            for payload in payloads:
                ok, reply = link.method(method, payload, family)
                assert not ok, (family, method, payload)
                assert method in reply["error"]
            expected_counts[link.keys.method(family, method)] = len(payloads)
    after = link.status()
    by_key = after["bad_input"]["by_key"]
    assert {key: by_key[key]["count"] for key in expected_counts} == expected_counts
    for field in ("state", "gains", "target", "command_timed_out"):
        assert after[field] == before[field], field
    torques, expected = link.cycle(moving(1))
    assert torques == expected and torques != [0.0, 0.0, 0.0], "still running, with the same gains and target"
    assert link.invoke(Method.CLEAR)["bad_input"]["total"] == 0, "clear resets the bad-input counters"


@pytest.mark.parametrize("family", list(MethodFamily))
def test_every_method_replies_with_the_status(link, family):
    link.reset(vx=0.1, w=0.0)
    assert link.invoke(Method.SET_PD_GAIN, DEFAULT_GAINS, family)["gains"] == msgspec.to_builtins(DEFAULT_GAINS)
    assert link.invoke(Method.FINISH, family=family)["state"] == "finished"
    assert link.invoke(Method.START, family=family)["state"] == "running"
    assert link.invoke(Method.STOP, family=family)["state"] == "stopped"
    ok, reply = link.method(Method.CLEAR, "{}", family)
    assert ok and reply["state"] == "running", "an explicit {} is accepted like an empty payload"
    for field in ("gains", "geometry", "offsets", "limits", "counters", "target_angle", "bad_input"):
        assert field in reply, field


def test_body_pose_becomes_the_sim_pose_on_both_keys(link):
    link.reset(vx=0.0, w=0.0)
    tm = Time(12, 345)
    # RH0 turned by -pi/2 (its forward +y along world +x): axle centre 0.045795 ahead in x, heading ~0
    data = [1.0, 2.0, 0.3, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
    link.put(link.keys.sim_body_pose, encode(TimedDoubleSeq(tm, data)))
    for collector in (link.pose_gui, link.pose_localization):
        pose = collector.get()
        assert pose.tm == tm
        assert pose.data == link.mirror.sim_pose(data)
        assert pose.data == pytest.approx([1.045795, 2.0, 0.3, 1.5708 - math.pi / 2], abs=1e-12)


def test_only_the_body_poses_of_observed_steps_become_sim_poses(link):
    """The simulator marks each step observed or not; the motor converts and publishes the body
    pose of an observed step only (a pose without a mark, as from a hand-made stream, always)."""
    link.reset(vx=0.0, w=0.0)
    identity_pose = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    skipped, seen = Time.from_nanoseconds(link.time_ns), Time.from_nanoseconds(link.time_ns + STEP_NS)
    publisher = link.publishers[link.keys.sim_body_pose]
    converted = link.counter("body_pose_samples")
    publisher.put(encode(TimedDoubleSeq(skipped, identity_pose)), attachment=encode_mark(None, observed=False))
    publisher.put(encode(TimedDoubleSeq(seen, identity_pose)), attachment=encode_mark(None, observed=True))
    for collector in (link.pose_gui, link.pose_localization):
        assert collector.get().tm == seen
        assert collector.drain() == [], "nothing for the step that is not observed"
    assert link.counter("body_pose_samples") == converted + 1, "the unobserved pose was not even converted"


def test_command_timeout_brakes_after_silence(link):
    link.reset(vx=0.5, w=0.0)
    link.cycle(moving(1))
    timeouts = link.counter("command_timeouts")
    silence_ns = round(CONFIG.motor.command_timeout * 1e9) + STEP_NS
    torques, expected = link.cycle(moving(2), dt_ns=silence_ns)
    assert torques == expected and link.mirror.command == (0.0, 0.0)
    status = link.status()
    assert status["command_timed_out"] and status["counters"]["command_timeouts"] == timeouts + 1
    link.target(0.5, 0.0)
    torques, expected = link.cycle(moving(3))
    assert torques == expected and link.mirror.command == (0.5, 0.0)


def test_status_reports_locked_parameters_and_counters(link):
    link.reset(vx=0.2, w=-0.1)
    published = link.status()["torques_published"]
    link.cycle(moving(1))
    status = link.status()
    assert status["service"] == "motor" and status["robot"] == ROBOT
    assert status["state"] == "running" and status["target_angle"] == CONFIG.motor.target_angle
    assert status["geometry"] == {
        "left_wheel_id": 1,
        "right_wheel_id": 2,
        "radius_of_left_wheel": CONFIG.robot.radius_of_left_wheel,
        "radius_of_right_wheel": 0.12,
        "length_of_axle": CONFIG.robot.length_of_axle,
        "left_radius": CONFIG.robot.radius_of_left_wheel,
        "right_radius": 0.12,
        "half_axle": CONFIG.robot.length_of_axle / 2.0,
    }
    assert status["offsets"]["simulated_offset_y"] == 0.045795
    limits = ("max_vx", "max_ax", "max_w", "max_aw")
    assert {name: status["limits"][name] for name in limits} == {name: OVERRIDES[f"motor.{name}"] for name in limits}
    assert status["limits"]["max_jerk_x"] is None, "every limit listed, those not set None"
    assert status["target"] == {"vx": 0.2, "w": -0.1}
    assert status["torques_published"] == published + 1
