"""``invent sim`` over real zenoh, with a torque source written here standing in for the motor control."""

from __future__ import annotations

import math
import queue
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh

from schemas.codec import ENCODING, decode, encode
from schemas.keys import Keys, Service
from schemas.messages import BumpEvent, NoArguments, TimedDoubleSeq
from schemas.topics import Method, MethodFamily
from services.clock.lockstep import StepMark, decode_mark, observed
from services.config import SimConfig
from services.runtime.inputs import contents
from sim_bridge.display import DISPLAY_VARIABLE
from tests.harness import Collector, InventProcess, refused, status_reply, wait_alive, wait_until

KEYS = Keys()
STEP_NS = 1_000_000
Torque = Callable[[TimedDoubleSeq], list[float]]


class TorqueSource:
    """Answers every ``sim/wheel_angles`` sample with a ``motor/torque`` carrying the same ``tm``.

    The zenoh callback only queues the sample; the test thread replies (:meth:`answer`). While
    :meth:`declare_alive` holds the motor's liveliness token, a lockstep sim waits for the answers;
    its ``motor/status`` then says whether it sees the simulator's token, as a motor's does, so a
    lockstep sim's first step does not wait out its start-up handshake for it.
    """

    def __init__(self, session: zenoh.Session, torque: Torque) -> None:
        self.torque = torque
        self.samples: queue.Queue[tuple[bytes, bytes | None]] = queue.Queue()
        self.answered: list[TimedDoubleSeq] = []
        self.marks: list[StepMark | None] = []
        """The mark of each sample answered."""
        self._session = session
        self._subscriber = session.declare_subscriber(
            KEYS.sim_wheel_angles, lambda sample: self.samples.put(contents(sample))
        )
        # BLOCK, as a lockstep motor's: zenoh's default DROP loses a put that finds the transmit queue
        # full, which a loaded machine does, and the sim then steps without that torque
        self.publisher = session.declare_publisher(
            KEYS.motor_torque, encoding=zenoh.Encoding(ENCODING), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._token: zenoh.LivelinessToken | None = None
        self._status: zenoh.Queryable | None = None
        self._sim_alive = False
        self._sim_tokens = session.liveliness().declare_subscriber(
            KEYS.alive(Service.SIM), self._on_sim_token, history=True
        )

    def _on_sim_token(self, sample: zenoh.Sample) -> None:
        self._sim_alive = sample.kind == zenoh.SampleKind.PUT

    def _on_status(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, msgspec.json.encode({"sim_alive": self._sim_alive}))

    def declare_alive(self) -> None:
        self._token = self._session.liveliness().declare_token(KEYS.alive(Service.MOTOR))
        self._status = self._session.declare_queryable(KEYS.status(Service.MOTOR), self._on_status)

    def withdraw(self) -> None:
        assert self._token is not None and self._status is not None
        self._token.undeclare()
        self._status.undeclare()
        self._token = self._status = None

    def answer_one(self, timeout: float = 10.0) -> TimedDoubleSeq:
        payload, attachment = self.samples.get(timeout=timeout)
        angles = decode(TimedDoubleSeq, payload)
        wait_until(lambda: self.publisher.matching_status.matching, what="the sim's motor/torque subscriber")
        self.publisher.put(encode(TimedDoubleSeq(tm=angles.tm, data=self.torque(angles))))
        self.answered.append(angles)
        self.marks.append(decode_mark(attachment, angles.tm.to_nanoseconds()))
        return angles

    def answer(self, count: int) -> None:
        for _ in range(count):
            self.answer_one()

    def answer_until_exit(self, sim: InventProcess) -> None:
        """Answer until the sim process has exited and no sample is left."""
        while True:
            try:
                self.answer_one(timeout=0.2)
            except queue.Empty:
                if sim.process.poll() is not None:
                    return

    def close(self) -> None:
        if self._token is not None:
            self.withdraw()
        self._sim_tokens.undeclare()
        self.publisher.undeclare()
        self._subscriber.undeclare()


def constant(left: float, right: float) -> Torque:
    return lambda _angles: [left, right]


def sim_process(endpoint: str, *flags: str) -> InventProcess:
    return InventProcess("sim", "--connect", endpoint, *flags)


def finish(sim: InventProcess) -> str:
    """Wait for a ``--duration`` run to end by itself; assert exit code 0 and return its stderr."""
    try:
        _out, err = sim.process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        sim.process.kill()
        raise AssertionError("invent sim --duration did not finish") from None
    assert sim.process.returncode == 0, err
    return err


def status(session: zenoh.Session) -> dict:
    return status_reply(session, KEYS, Service.SIM)


def yaw(data: list[float]) -> float:
    return math.atan2(data[6], data[3])


EVERY_STEP = ("--set", "sim.observe_every=1")
"""The seeds' behaviour: every step observed, so every step has its body pose."""


def run_with_source(
    session: zenoh.Session, endpoint: str, torque: Torque, *flags: str, source: TorqueSource | None = None
) -> tuple[list, list, str]:
    """One lockstep ``--duration`` run answered by a TorqueSource; (wheel angles answered, body poses, stderr)."""
    poses = Collector(session, KEYS.sim_body_pose, TimedDoubleSeq)
    source = source or TorqueSource(session, torque)
    source.declare_alive()
    try:
        with sim_process(endpoint, *flags) as sim:
            source.answer_until_exit(sim)
            err = finish(sim)
        return source.answered, poses.drain(), err
    finally:
        source.close()
        poses.close()


def test_wheel_angles_every_step_body_pose_and_clock_at_the_observed_steps(session, endpoint):
    clock = Collector(session, KEYS.sim_clock, TimedDoubleSeq)
    source = TorqueSource(session, constant(2.0, 2.0))
    answered, poses, err = run_with_source(session, endpoint, constant(2.0, 2.0), "--duration", "0.5", source=source)
    expected_tms = [k * STEP_NS for k in range(501)]
    assert [a.tm.to_nanoseconds() for a in answered] == expected_tms, "one sample per 1 ms step, and the end state"
    every = SimConfig().observe_every
    observed_tms = [k * STEP_NS for k in range(0, 501, every)]
    assert [p.tm.to_nanoseconds() for p in poses] == observed_tms, f"a body pose every {every} steps"
    clocks = clock.drain()
    assert [c.tm for c in clocks] == [a.tm for a in answered[::every]], "sim/clock: the observed steps"
    assert [c.data for c in clocks] == [a.data for a in answered[::every]], "with their wheel angles"
    assert [observed(mark) for mark in source.marks] == [k % every == 0 for k in range(501)]
    assert all(mark is not None and mark.owed == {} for mark in source.marks), "lockstep, no participant"
    assert all(len(a.data) == 2 for a in answered) and all(len(p.data) == 12 for p in poses)
    # The end state's torque is taken, never applied: the run ends there.
    assert "finished: 500 steps" in err and "torques_applied 500" in err and "long_waits 0" in err


@pytest.mark.parametrize("every", [30, 1000])
def test_the_end_of_a_finite_run_is_observed_whatever_the_observed_steps(session, endpoint, every: int):
    clock = Collector(session, KEYS.sim_clock, TimedDoubleSeq)
    _answered, poses, err = run_with_source(
        session, endpoint, constant(2.0, 2.0), "--duration", "0.5", "--set", f"sim.observe_every={every}"
    )
    end_ns = 500 * STEP_NS
    expected = [*(k * STEP_NS for k in range(0, 500, every)), end_ns]
    assert [p.tm.to_nanoseconds() for p in poses] == expected, "the observed steps, then the end at 0.5 s"
    assert [c.tm.to_nanoseconds() for c in clock.drain()] == expected
    assert "finished: 500 steps, 0.500 s simulated" in err


def test_an_observer_token_adds_the_steps_of_its_rate(session, endpoint):
    """The ROS 2 bridge's ``observes`` token, held here: the steps of a 100 Hz grid are observed too."""
    token = session.liveliness().declare_token(KEYS.observes(Service.ROS2, 100.0))
    try:
        _answered, poses, err = run_with_source(session, endpoint, constant(1.0, 1.0), "--duration", "0.2")
    finally:
        token.undeclare()
    # From 50 ms on: the token reaches the sim within its first steps, on a busy machine too.
    assert [p.tm.to_nanoseconds() for p in poses if p.tm.to_nanoseconds() >= 50 * STEP_NS] == [
        k * STEP_NS for k in range(50, 201, 10)
    ]
    assert "ros2 observes at 100 Hz" in err


def test_the_step_flag_sets_the_simulation_time_increment(session, endpoint):
    answered, poses, err = run_with_source(
        session, endpoint, constant(1.0, 1.0), "--step", "0.002", "--duration", "0.02", *EVERY_STEP
    )
    assert [a.tm.to_nanoseconds() for a in answered] == [k * 2 * STEP_NS for k in range(11)]
    assert [p.tm.to_nanoseconds() for p in poses] == [k * 2 * STEP_NS for k in range(11)]
    assert "finished: 10 steps, 0.020 s simulated" in err


def test_constant_positive_torque_drives_forward_on_a_proper_rotation(session, endpoint):
    answered, poses, _err = run_with_source(session, endpoint, constant(2.0, 2.0), "--duration", "0.5")
    first, last = poses[0].data, poses[-1].data
    assert first[:3] == pytest.approx([0.0, 0.0, 0.1])
    assert last[0] > 0.05 and abs(last[1]) < 1e-4 and abs(yaw(last)) < 1e-4
    left, right = answered[-1].data
    assert left > 1.0 and right > 1.0, "positive torque turns both wheels forward"
    for pose in poses:
        matrix = np.array(pose.data[3:]).reshape(3, 3)
        np.testing.assert_allclose(matrix @ matrix.T, np.eye(3), atol=1e-9)
        assert np.linalg.det(matrix) == pytest.approx(1.0, abs=1e-9)


def test_opposite_torques_spin_the_robot_in_place(session, endpoint):
    answered, poses, _err = run_with_source(session, endpoint, constant(2.0, -2.0), "--duration", "0.5")
    last = poses[-1].data
    assert yaw(last) < -0.1 and math.hypot(last[0], last[1]) < 0.01
    left, right = answered[-1].data
    assert left > 0.5 and right < -0.5


def wobbly(angles: TimedDoubleSeq) -> list[float]:
    t = angles.tm.to_seconds()
    return [2.0 + 3.0 * math.sin(7.0 * t), 1.0 + 2.0 * math.cos(11.0 * t)]


def test_two_lockstep_runs_with_the_same_torques_are_bit_identical(session, endpoint):
    runs = [run_with_source(session, endpoint, wobbly, "--duration", "0.4", *EVERY_STEP) for _ in range(2)]
    (angles_a, poses_a, _), (angles_b, poses_b, _) = runs
    assert len(poses_a) == len(poses_b) == 401, "every step's pose, and the end state's"
    assert poses_a[-1].data == poses_b[-1].data
    assert [p.data for p in poses_a] == [p.data for p in poses_b]
    assert [a.data for a in angles_a] == [a.data for a in angles_b]
    assert poses_a[-1].data[0] > 0.05, "the torques did act"


def test_lockstep_without_a_torque_source_finishes_a_one_second_run(session, endpoint):
    angles = Collector(session, KEYS.sim_wheel_angles, TimedDoubleSeq)
    with sim_process(endpoint, "--duration", "1") as sim:
        err = finish(sim)
    assert "finished: 1000 steps" in err and "missing_torques 1000" in err
    assert max(a.tm.to_nanoseconds() for a in angles.drain()) == 1000 * STEP_NS, "and the end state at 1 s"


def test_a_motor_control_alive_is_waited_for_as_long_as_it_lives_said_at_each_timeout(session, endpoint):
    source = TorqueSource(session, constant(2.0, 2.0))
    source.declare_alive()
    try:
        with sim_process(endpoint, "--set", "sim.lockstep_timeout=0.05") as sim:
            wait_alive(session, KEYS.alive(Service.SIM))
            waiting = wait_until(
                lambda: (reply := status(session))["counters"]["long_waits"] and reply, what="a long wait"
            )
            time.sleep(0.5)  # ten timeouts: a give-up would have stepped on
            still = status(session)
            assert waiting["steps"] == still["steps"] == 0, "the first step waits for its torque"
            assert still["counters"]["long_waits"] == 1, "counted once per step, however long it waits"
            assert still["counters"]["missing_torques"] == 0 and still["motor_silent"] is False

            while (answered := status(session))["counters"]["torques_applied"] < 200:
                source.answer(100)
            assert answered["torques"] == [2.0, 2.0] and answered["counters"]["missing_torques"] == 0
            code, _out, err = sim.stop()
        assert code == 0, err
        assert "still waiting for motor/torque for t = 0.000 s after " in err
        assert "s: its motor control is alive" in err
    finally:
        source.close()


def test_a_late_torque_source_is_paced_until_it_answers_then_waited_for_and_a_dead_one_dropped(session, endpoint):
    source = TorqueSource(session, constant(2.0, 2.0))
    try:
        with sim_process(endpoint) as sim:
            wait_alive(session, KEYS.alive(Service.SIM))
            wait_until(lambda: status(session)["steps"] > 200, what="free running without a motor")
            assert status(session)["motor_alive"] is False

            bad = encode(TimedDoubleSeq(tm=source.answer_one().tm, data=[1.0, 2.0, 3.0]))
            source.publisher.put(bad)
            wait_until(lambda: status(session)["bad_input"]["total"] >= 1, what="the 3-torque message counted")

            source.declare_alive()
            silent = wait_until(lambda: (reply := status(session))["motor_silent"] and reply, what="a silent motor")
            wait_until(lambda: status(session)["steps"] > silent["steps"] + 50, what="paced steps with zero torque")
            while (before := status(session))["counters"]["torques_applied"] < 300:
                source.answer(100)  # first the backlog from the free-running steps, all stale
            assert before["counters"]["stale_torques"] >= 1, "answers to samples from before the wait are ignored"
            assert before["motor_silent"] is False and before["torques"] == [2.0, 2.0]

            waiting_on = decode(TimedDoubleSeq, source.samples.get(timeout=5)[0]).tm.to_nanoseconds() // STEP_NS
            for _ in range(3):
                assert status(session)["steps"] == waiting_on, "the sim waits for the unanswered step"

            source.withdraw()
            wait_until(lambda: not status(session)["motor_alive"], timeout=5, what="the sim to drop the dead source")
            wait_until(lambda: status(session)["steps"] > waiting_on + 500, timeout=5, what="stepping on")
            code, _out, err = sim.stop()
        assert code == 0, err
        assert "motor control alive after the first step: stepping at real-time pace" in err
        assert "motor control answers: steps wait for its torques" in err
    finally:
        source.close()


def test_realtime_mode_holds_its_pace_and_applies_the_newest_torque(session, endpoint):
    factor, arrivals = 2.0, queue.Queue()
    subscriber = session.declare_subscriber(
        KEYS.sim_body_pose, lambda sample: arrivals.put((time.monotonic(), sample.payload.to_bytes()))
    )
    source = TorqueSource(session, constant(2.0, 2.0))
    try:
        with sim_process(endpoint, "--mode", "realtime", "--realtime-factor", str(factor), "--duration", "1") as sim:
            source.answer_until_exit(sim)
            err = finish(sim)
    finally:
        source.close()
        subscriber.undeclare()
    received = []
    while not arrivals.empty():
        wall, payload = arrivals.get()
        received.append((wall, decode(TimedDoubleSeq, payload)))
    (wall_first, first), (wall_last, last) = received[0], received[-1]
    achieved = (last.tm.to_seconds() - first.tm.to_seconds()) / (wall_last - wall_first)
    print(f"realtime factor {factor}: achieved {achieved:.3f} over {len(received)} steps")
    assert 0.3 * factor < achieved < 1.2 * factor
    assert last.data[0] > 0.05, "the source's torque was applied"
    assert "finished: 1000 steps" in err


def test_driving_into_the_box_publishes_sim_bump_and_calls_motor_bump_stop(session, endpoint):
    stop_calls: queue.Queue[bytes] = queue.Queue()

    def on_stop(query: zenoh.Query) -> None:
        stop_calls.put(query.payload.to_bytes() if query.payload is not None else b"")
        query.reply(query.key_expr, b"{}", encoding=zenoh.Encoding(ENCODING))

    bumps = Collector(session, KEYS.sim_bump, BumpEvent)
    with session.declare_queryable(KEYS.method(MethodFamily.BUMP, Method.STOP), on_stop):
        _answered, poses, err = run_with_source(
            session, endpoint, constant(3.0, 3.0), "--world", "bump", "--duration", "1.5"
        )
    bump = bumps.get(timeout=1)
    assert bump.obstacle == "box" and bump.x == pytest.approx(0.9, abs=1e-3) and abs(bump.y) < 0.45
    assert 0.2 < bump.tm.to_seconds() < 1.5
    assert bumps.drain() == [], "one contact, one bump"
    decode(NoArguments, stop_calls.get(timeout=1))
    assert stop_calls.empty()
    assert "bumps 1" in err and "bump_stop_calls 1" in err and "bump_stop_acks 1" in err
    assert poses[-1].data[0] == pytest.approx(0.45, abs=0.01), "the box stops the robot"


def test_gui_without_a_display_exits_2_naming_the_problem(endpoint):
    sim = InventProcess("sim", "--connect", endpoint, "--gui", env={DISPLAY_VARIABLE: ""})
    _out, err = sim.process.communicate(timeout=30)
    assert sim.process.returncode == 2
    assert "--gui needs a display" in err


def test_a_bad_world_file_exits_2_naming_the_field(endpoint, tmp_path: Path, capsys):
    world = tmp_path / "bad.toml"
    world.write_text('[[boxes]]\nname = "b"\nx = "far"\ny = 0\nsize = [1, 1, 1]\n')
    code, _out, err = refused(capsys, "sim", "--connect", endpoint, "--world", str(world))
    assert code == 2
    assert "boxes[0].x" in err
