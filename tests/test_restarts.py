"""Safe restarts, with the real services: a stopped motor comes back stopped with its gains, and a
localization restarted while the simulator runs does not send odometry back to its initial pose."""

from __future__ import annotations

import json
import signal

import pytest

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import PDGains, Time, TimedDoubleSeq, TimedPosition
from schemas.topics import Method, MethodFamily
from tests.harness import Collector, InventProcess, call, wait_alive, wait_until
from tests.sim_presence import SimPresence

pytestmark = pytest.mark.slow

KEYS = Keys("restarted")
TUNED = PDGains(p_gain_l=3.5, p_gain_r=3.25, d_gain_l=1.5, d_gain_r=1.25)


def _method(session, method: Method, payload: bytes | None = None) -> dict:
    ok, status = call(session, KEYS.method(MethodFamily.GUI, method), payload)
    assert ok, status
    return status


def _kill(process: InventProcess, session) -> None:
    """SIGKILL, as a crash: no clean shutdown, no last write."""
    process.process.send_signal(signal.SIGKILL)
    process.process.communicate()
    wait_until(
        lambda: not any(r.ok for r in session.liveliness().get(KEYS.alive(Service.MOTOR), timeout=1.0)),
        what="the killed motor's token to go",
    )


def _motor(endpoint: str, state_file) -> InventProcess:
    return InventProcess("motor", "--connect", endpoint, "--robot", KEYS.robot, "--state", str(state_file))


def test_a_stopped_motor_killed_and_restarted_comes_back_stopped_with_its_gains(endpoint, session, tmp_path):
    state_file = tmp_path / "motor.json"
    with _motor(endpoint, state_file) as motor:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        _method(session, Method.SET_PD_GAIN, encode(TUNED))
        assert _method(session, Method.STOP)["state"] == "stopped"
        _kill(motor, session)
    with _motor(endpoint, state_file) as motor:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        ok, status = call(session, KEYS.status(Service.MOTOR))
        assert ok and status["state"] == "stopped"
        assert status["gains"] == {"p_gain_l": 3.5, "p_gain_r": 3.25, "d_gain_l": 1.5, "d_gain_r": 1.25}
        assert status["restored"]["stopped"] is True and status["restored"]["from"] == str(state_file)
        assert _method(session, Method.CLEAR)["state"] != "stopped"
        code, _out, err = motor.stop()
        assert code == 0 and "STOPPED (emergency stop latched" in err
    with _motor(endpoint, state_file) as motor:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        ok, status = call(session, KEYS.status(Service.MOTOR))
        assert ok and status["state"] != "stopped", "cleared, it stays cleared"
        assert status["gains"] == json.loads(state_file.read_text())["gains"]
        motor.stop()


def test_a_motor_whose_state_file_is_unreadable_starts_stopped(endpoint, session, tmp_path):
    state_file = tmp_path / "motor.json"
    state_file.write_text('{"stopped": fal')
    with _motor(endpoint, state_file) as motor:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        ok, status = call(session, KEYS.status(Service.MOTOR))
        assert ok and status["state"] == "stopped" and "error" in status["restored"]
        code, _out, err = motor.stop()
    assert code == 0 and "unreadable" in err


def test_a_localization_restarted_while_the_sim_runs_fixes_the_current_pose_first(endpoint, session):
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    current = [1.5, -0.5, 0.05, 2.0]
    with SimPresence(endpoint, KEYS):
        publisher = session.declare_publisher(KEYS.motor_sim_pose_localization)
        with InventProcess("localization", "--connect", endpoint, "--robot", KEYS.robot) as localization:
            wait_alive(session, KEYS.alive(Service.LOCALIZATION))
            wait_until(lambda: publisher.matching_status.matching, what="the localization subscriber")
            stamp_ns = 30_000_000_000  # the simulator has been running for 30 s

            def first_fix() -> TimedPosition | None:
                nonlocal stamp_ns
                stamp_ns += 10_000_000
                publisher.put(encode(TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), current)))
                return next(iter(fixes.drain()), None)

            fix = wait_until(first_fix, 10, "the first fix")
            assert (fix.x, fix.y, fix.theta) == (1.5, -0.5, 2.0), "the simulated pose, not the initial (0, 0, 0)"
            ok, status = call(session, KEYS.status(Service.LOCALIZATION))
            assert ok and status["first_fix_from_sim_pose"] is True
            localization.stop()
    fixes.close()


def test_a_state_file_that_cannot_be_written_does_not_stop_the_stop(endpoint, session, tmp_path):
    blocked = tmp_path / "not-a-directory"
    blocked.write_text("")
    with _motor(endpoint, blocked / "motor.json") as motor:
        wait_alive(session, KEYS.alive(Service.MOTOR))
        assert _method(session, Method.STOP)["state"] == "stopped"
        code, _out, err = motor.stop()
    assert code == 0 and "will not survive a restart" in err
