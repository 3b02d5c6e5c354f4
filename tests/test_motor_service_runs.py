"""``invent motor`` in processes of their own over real zenoh, each test's own: ``--trace`` and the
command timeout's warning, a reconnected and a restarted simulator, two sim runs in a row, bad
configuration (tests/test_motor_service.py: the shared process checked against MotorCore as a mirror,
and its helpers).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedVelocity
from schemas.topics import Topic
from services.clock.lockstep import encode_mark
from services.config import TargetAngleMode, load_config
from services.motor.core import MotorCore
from tests.harness import (
    InventProcess,
    free_port,
    json_lines,
    run_invent,
    wait_alive,
    wait_until,
)
from tests.sim_presence import SimPresence
from tests.test_motor_service import OVERRIDES, STEP_NS, TRACE_FIELDS, MotorLink, moving, set_flags


def test_trace_lines_and_command_timeout_warning_in_an_integrated_motor(tmp_path: Path, endpoint, session):
    """Own process: --trace writes one JSON line per cycle (matching the torques published), and
    a command timeout logs one warning per silence."""
    trace = tmp_path / "motor.jsonl"
    robot = "mot2"
    config = load_config(overrides={"robot.name": robot, "motor.target_angle": TargetAngleMode.INTEGRATED})
    keys = Keys(robot)
    motor_link = MotorLink(session, keys, config)
    try:
        with InventProcess(
            "motor",
            "--connect",
            endpoint,
            "--robot",
            robot,
            "--target-angle",
            TargetAngleMode.INTEGRATED,
            "--trace",
            str(trace),
        ) as motor:
            wait_alive(session, keys.alive(Service.MOTOR))
            motor_link.wait_matched()
            published = [motor_link.cycle([0.0, 0.0])[0], motor_link.cycle([0.001, 0.001])[0]]
            assert published == [[0.0, 0.0], [0.0, 0.0]], "zero on the first sample and while idle"
            motor_link.target(0.5, 0.0)
            for k in range(2, 6):
                torques, expected = motor_link.cycle([0.004 * k, 0.003 * k])
                assert torques == expected
                published.append(torques)
            silence_ns = round(config.motor.command_timeout * 1e9) + STEP_NS
            for dt_ns in (silence_ns, STEP_NS):
                published.append(motor_link.cycle([0.03, 0.03], dt_ns)[0])
            code, _out, err = motor.stop()
    finally:
        motor_link.close()
    assert code == 0, err
    records = json_lines(trace.read_text())
    assert len(records) == len(published)
    assert [record["torque"] for record in records] == published
    assert [record["state"] for record in records[:3]] == ["idle", "idle", "running"]
    # The default acceleration limit ramps the command: max_ax · 1 ms on the first cycle.
    ramped_vx = config.motor.max_ax * STEP_NS / 1e9
    assert records[2]["target"] == [0.5, 0.0] and records[2]["command"] == pytest.approx([ramped_vx, 0.0])
    assert records[2]["dq_ref"] == pytest.approx([ramped_vx / config.robot.radius_of_left_wheel] * 2)
    assert records[-1]["command"] == [0.0, 0.0]
    assert set(records[0]) == TRACE_FIELDS
    assert err.count("braking to zero") == 1


def test_a_reconnected_simulator_costs_nothing_and_a_restarted_one_is_answered_from_its_new_clock(endpoint, session):
    """Own process. A simulator plays 0, 1, 2 ... ms; its token goes and comes back while its
    clock goes on (a reconnection): every sample is answered as if nothing happened, and a lockstep
    sample held for its target when the token comes back is answered once the target comes. Then a new
    simulator plays from 0 again, its drive's first target arriving before its first sample:
    the motor answers it as a fresh motor would, and refuses nothing."""
    robot = "mot3"
    keys = Keys(robot)
    # No command timeout: the target history is then the stamp horizon (1 s), and targets do not age out.
    overrides = {**OVERRIDES, "motor.command_timeout": 0.0}
    config = load_config(overrides={"robot.name": robot, **overrides})
    motor_link = MotorLink(session, keys, config)
    samples = 12

    def sim_alive(alive: bool) -> None:
        wait_until(lambda: motor_link.status()["sim_alive"] is alive, what=f"the motor to see sim_alive {alive}")

    def answered_from_zero() -> None:
        motor_link.time_ns = -STEP_NS  # the first sample is stamped 0
        answers = [motor_link.cycle(moving(k)) for k in range(samples)]
        assert answers[0][0] == [0.0, 0.0, 0.0], "the first sample of a clock only initialises"
        for torques, expected in answers[1:]:
            assert torques == expected and torques[1] != 0.0

    try:
        with InventProcess("motor", "--connect", endpoint, "--robot", robot, *set_flags(overrides)) as motor:
            wait_alive(session, keys.alive(Service.MOTOR))
            motor_link.wait_matched()
            motor_link.time_ns = 0
            motor_link.target(0.4, 0.3)
            with SimPresence(endpoint, keys) as sim:
                sim_alive(True)
                motor_link.mirror = MotorCore(config.robot, config.motor)
                motor_link.mirror.set_target(0.4, 0.3, 0)
                answered_from_zero()
                sim.leave(session)
                sim_alive(False)
            with SimPresence(endpoint, keys) as sim:
                sim_alive(True)
                # Steps of 0.1 s: the clock goes on past the 1 s of target history the motor keeps, so
                # the next run's first target is older than that by the old time base.
                for k in range(samples, 2 * samples):
                    torques, expected = motor_link.cycle(moving(k), 100 * STEP_NS)
                    assert torques == expected and torques[1] != 0.0, "a reconnection costs no zero-torque cycle"
                assert motor_link.counter("time_base_restarts") == 0
                sim.leave(session)
                sim_alive(False)
            # Lockstep: a sample held for the drive's target, then the token appears (the clock now
            # decides) before that target comes. The target is of the old time base: taken at once,
            # not kept for a next sample that the simulator, waiting for this torque, never sends.
            held_ns, target_ns = motor_link.time_ns + STEP_NS, motor_link.time_ns + STEP_NS // 2
            held = TimedDoubleSeq(Time.from_nanoseconds(held_ns), moving(2 * samples))
            owed = encode_mark({Topic.DRIVE_TARGET_VELOCITY: target_ns}, observed=True)
            motor_link.publishers[keys.sim_wheel_angles].put(encode(held), attachment=owed)
            wait_until(lambda: motor_link.status()["lockstep_holds"]["held"] == 1, what="the sample to be held")
            with SimPresence(endpoint, keys) as sim:
                sim_alive(True)
                motor_link.put(
                    keys.drive_target_velocity,
                    encode(TimedVelocity(Time.from_nanoseconds(target_ns), [], 0.3, 0.0, 0.2, [])),
                )
                torque = motor_link.torques.get()
                motor_link.mirror.set_target(0.3, 0.2, target_ns)
                assert torque.tm == held.tm and torque.data == motor_link.mirror.step(held_ns, held.data)
                assert motor_link.passed_on.get() == held
                motor_link.time_ns = held_ns
                sim.leave(session)
                sim_alive(False)
            with SimPresence(endpoint, keys) as sim:
                sim_alive(True)
                targets_taken = motor_link.status()["inputs"][keys.drive_target_velocity]["samples"]
                motor_link.put(keys.drive_target_velocity, encode(TimedVelocity(Time(0, 0), [], 0.2, 0.0, -0.1, [])))
                wait_until(
                    lambda: motor_link.status()["inputs"][keys.drive_target_velocity]["samples"] > targets_taken,
                    what="the new run's first target to reach the motor",
                )
                motor_link.mirror = MotorCore(config.robot, config.motor)
                motor_link.mirror.set_target(0.2, -0.1, 0)
                answered_from_zero()
                sim.leave(session)
            status = motor_link.status()
            code, _out, err = motor.stop()
    finally:
        motor_link.close()
    assert code == 0, err
    assert motor_link.torques.drain() == [], "exactly one torque per sample"
    assert status["bad_input"]["total"] == 0, status["bad_input"]
    assert status["target"] == {"vx": 0.2, "w": -0.1}, "the new run's first target, taken once its clock decided"
    assert status["counters"]["time_base_restarts"] == 1
    assert status["counters"]["wheel_angle_samples"] == 3 * samples + 1
    assert err.count("a new simulator") == 1


def sim_summary(stderr: str) -> dict[str, int]:
    """The counters of ``invent sim``'s last log line: "finished: ...; torques_applied 300, ...; pose ..."."""
    summary = stderr.rsplit("finished: ", 1)[1].split(";")[1]
    return {name: int(count) for name, count in (item.split() for item in summary.split(","))}


def test_two_sim_runs_in_a_row_both_get_their_torques(endpoint, session):
    """The real simulator, run twice against one motor: the second run's clock starts at 0 again."""
    robot = "mot4"
    keys = Keys(robot)
    flags = ("--connect", endpoint, "--robot", robot)
    with InventProcess("motor", *flags) as motor:
        wait_alive(session, keys.alive(Service.MOTOR))
        for run in range(2):
            result = run_invent("sim", *flags, "--duration", "0.3", "--log-level", "info")
            assert result.returncode == 0, result.stderr
            counters = sim_summary(result.stderr)
            assert counters["torques_applied"] == 300, (run, counters)
            assert counters["missing_torques"] == 0, (run, counters)
        code, _out, err = motor.stop()
    assert code == 0, err


@pytest.mark.parametrize(
    ("flags", "field"),
    [(("--set", "motor.target_angle=bogus"), "target_angle"), (("--trace", "/nonexistent/dir/trace.jsonl"), "--trace")],
)
def test_bad_configuration_exits_2_naming_the_field(flags, field):
    result = run_invent("motor", "--connect", f"tcp/127.0.0.1:{free_port()}", *flags)
    assert result.returncode == 2, result.stderr
    assert field in result.stderr
