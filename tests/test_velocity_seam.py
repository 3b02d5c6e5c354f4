"""The velocity seam (``motor.output = "velocity"``, docs/plant.md): the motor sends wheel speed
targets on ``motor/wheel_velocity`` and the plant's own velocity loop follows them.

The sim's torque policy, pure: a step's targets applied in lockstep, the newest fresh ones in
realtime, those beyond ``input.max_wheel_speed`` refused. Over real zenoh: ``invent sim`` follows a stand-in motor's targets, and refuses and counts targets
that are not finite, beyond ``input.max_wheel_speed`` or of the wrong length, without moving. The
whole loop (``invent up --set motor.output=velocity --scenario square``, lockstep, composed) on the
PyBullet and the kinematic engines: home within 2 cm by the ground truth, the odometry within 1 cm
of it, and two runs the same bit for bit."""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from schemas.codec import ENCODING, BadInput, encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq
from services.config import InputConfig, SimConfig, SimMode
from services.exits import ExitStatus
from services.recording.mcap_files import RecordedMessage, read_messages
from sim_bridge.latency import TorqueLatency
from sim_bridge.progress import RunProgress
from sim_bridge.torque_policy import TORQUE_COUNTERS, TorquePolicy
from tests.harness import REPO, invent_command, wait_alive, wait_until
from tests.test_sim_bridge import TorqueSource, constant, run_with_source, sim_process, status
from tests.test_torque_policy import STEP_NS, Events, Wheels

KEYS = Keys()
VELOCITY = ("--set", "motor.output=velocity")
HOME_TOLERANCE_M = 0.02
ODOMETRY_TOLERANCE_M = 0.01
COMPARED = (
    KEYS.sim_wheel_angles,
    KEYS.sim_body_pose,
    KEYS.motor_wheel_velocity,
    KEYS.odometry_pose,
    KEYS.drive_target_velocity,
)


class VelocityWheels(Wheels):
    """The policy's fake wheels, taking wheel speed targets too."""

    def __init__(self) -> None:
        super().__init__()
        self.targets: list[float] | None = None

    def set_wheel_velocities(self, targets: Sequence[float]) -> None:
        self.targets, self.braking = list(targets), False


def velocity_policy(mode: SimMode) -> tuple[TorquePolicy, VelocityWheels, RunProgress, dict[str, int]]:
    wheels, progress, counters = VelocityWheels(), RunProgress(), dict.fromkeys(TORQUE_COUNTERS, 0)
    policy = TorquePolicy(
        wheels,
        SimConfig(mode=mode),
        STEP_NS,
        progress=progress,
        counters=counters,
        latency=TorqueLatency(STEP_NS),
        events=Events(),
        now_ns=lambda: 0,
        max_wheel_speed=InputConfig().max_wheel_speed,
    )
    policy.set_motor_alive(True)
    return policy, wheels, progress, counters


def targets(tm_ns: int, left: float, right: float) -> TimedDoubleSeq:
    return TimedDoubleSeq(Time.from_nanoseconds(tm_ns), [left, right])


def test_the_policy_applies_a_steps_wheel_speed_targets_in_lockstep_and_refuses_those_beyond_the_bound():
    policy, wheels, _, counters = velocity_policy(SimMode.LOCKSTEP)
    limit = InputConfig().max_wheel_speed
    policy.begin_wait(3 * STEP_NS)
    with pytest.raises(BadInput, match="max_wheel_speed"):
        policy.on_wheel_velocity(targets(3 * STEP_NS, limit * 1.01, 0.0), None)
    assert wheels.targets is None and not policy.settled(), "refused: nothing applied, still awaited"
    policy.on_wheel_velocity(targets(3 * STEP_NS, 2.0, -limit), None)
    assert policy.settled() and wheels.targets == [2.0, -limit]
    policy.end_wait(3, final=False)
    assert counters["torques_applied"] == 1


def test_the_policy_applies_the_newest_fresh_wheel_speed_targets_in_realtime():
    policy, wheels, progress, counters = velocity_policy(SimMode.REALTIME)
    progress.published_ns = 5 * STEP_NS
    policy.on_wheel_velocity(targets(5 * STEP_NS, 1.0, 1.5), None)
    policy.realtime(5 * STEP_NS, 5)
    assert wheels.targets == [1.0, 1.5] and counters["torques_applied"] == 1
    policy.realtime(100 * STEP_NS, 100)  # older than sim.torque_max_age: zero torque
    assert wheels.torques == [0.0, 0.0] and counters["missing_torques"] == 1


def velocity_source(session: zenoh.Session, left: float, right: float) -> TorqueSource:
    """A stand-in motor answering every wheel-angle sample with these wheel speed targets."""
    source = TorqueSource(session, constant(left, right))
    source.publisher.undeclare()
    source.publisher = session.declare_publisher(KEYS.motor_wheel_velocity, encoding=zenoh.Encoding(ENCODING))
    return source


@pytest.mark.parametrize("engine", ["kinematic", "pybullet"])
def test_the_sim_follows_wheel_speed_targets(session, endpoint, engine: str):
    source = velocity_source(session, 3.0, 3.0)
    answered, poses, err = run_with_source(
        session, endpoint, constant(3.0, 3.0), "--engine", engine, "--duration", "1", *VELOCITY, source=source
    )
    assert len(answered) == 1001 and "long_waits 0" in err
    x, y = poses[-1].data[0], poses[-1].data[1]
    assert x == pytest.approx(0.3, abs=0.01) and abs(y) < 1e-3, "3 rad/s of a 0.1 m wheel for 1 s"


def test_bad_wheel_speed_targets_are_refused_counted_and_move_nothing(session, endpoint):
    limit = InputConfig().max_wheel_speed
    with sim_process(endpoint, "--engine", "kinematic", *VELOCITY) as sim:
        wait_alive(session, KEYS.alive(Service.SIM))
        wait_until(lambda: status(session)["steps"] > 100, what="stepping")
        publisher = session.declare_publisher(KEYS.motor_wheel_velocity, encoding=zenoh.Encoding(ENCODING))
        try:
            wait_until(lambda: publisher.matching_status.matching, what="the sim's motor/wheel_velocity subscriber")
            tm = Time.from_nanoseconds(status(session)["steps"] * 1_000_000)
            for data in ([limit * 2, 0.0], [1.0, 1.0, 1.0]):
                publisher.put(encode(TimedDoubleSeq(tm=tm, data=data)))
            publisher.put(b'{"tm": {"sec": 0, "nsec": 0}, "data": [1e999, 0.0]}')  # inf: not finite
            wait_until(lambda: status(session)["bad_input"]["total"] >= 3, what="the three bad targets counted")
            current = status(session)
            entry = current["bad_input"]["by_key"][KEYS.motor_wheel_velocity]
            assert entry["count"] == 3 and current["counters"]["stale_torques"] == 0
            assert current["pose"]["x"] == 0.0 and current["pose"]["y"] == 0.0, "nothing applied"
            wait_until(lambda: status(session)["steps"] > current["steps"] + 100, what="the sim steps on")
        finally:
            publisher.undeclare()
        code, _out, err = sim.stop()
    assert code == 0, err


@dataclass
class Run:
    returncode: int
    output: str
    report: dict
    messages: list[RecordedMessage]

    def on(self, key: str) -> list[bytes]:
        return [message.data for message in self.messages if message.topic == key]


def up(report: Path, engine: str) -> Run:
    result = subprocess.run(
        invent_command(
            "up",
            "--engine",
            engine,
            "--composed",
            "--mode",
            "lockstep",
            "--report",
            str(report),
            "--scenario",
            "square",
            *VELOCITY,
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    output = result.stdout + result.stderr
    report_file = report / "report.json"
    assert report_file.is_file(), output[-4000:]
    return Run(
        result.returncode, output, json.loads(report_file.read_text()), read_messages(report / "run.mcap").messages
    )


@pytest.fixture(scope="module", params=[pytest.param("kinematic", marks=pytest.mark.kinematic), "pybullet"])
def squares(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Run, Run]:
    folder = tmp_path_factory.mktemp(f"velocity_square_{request.param}")
    return up(folder / "first", request.param), up(folder / "second", request.param)


@pytest.mark.slow
def test_the_square_in_velocity_mode_comes_home_within_2_cm_with_the_odometry_within_1_cm(squares):
    run = squares[0]
    assert run.returncode == ExitStatus.OK, run.output[-4000:]
    assert run.report["outcome"]["outcome"] == "completed" and run.report["mode"] == "lockstep"
    truth = run.report["final"]["ground_truth"]
    assert math.hypot(truth["x"], truth["y"]) < HOME_TOLERANCE_M, truth
    assert run.report["odometry_error"]["max_m"] < ODOMETRY_TOLERANCE_M, run.report["odometry_error"]
    assert run.report["health"]["torques"]["late"] == 0 and not run.report["degraded"]
    assert run.on(KEYS.motor_wheel_velocity) and not run.on(KEYS.motor_torque), "targets, not torques"
    motor = json.loads(run.on(KEYS.status(Service.MOTOR))[-1])
    assert motor["output"] == "velocity" and motor["torques_published"] == 0
    assert all(count == 0 for count in run.report["bad_inputs"].values()), run.report["bad_inputs"]


@pytest.mark.slow
def test_two_lockstep_runs_in_velocity_mode_give_the_same_samples_bit_for_bit(squares):
    first, second = squares
    assert second.returncode == ExitStatus.OK, second.output[-4000:]
    for key in COMPARED:
        samples = first.on(key)
        assert samples, f"{key} recorded"
        assert samples == second.on(key), f"{key} differs between two lockstep runs"
