"""The exit statuses of ``invent`` (services/exits.py): their numbers, and real runs that end with them."""

from __future__ import annotations

from services.drive.outcome import Outcome
from services.exits import ExitStatus
from services.launch.run import outcome_exit_code
from services.runtime.session import free_port
from tests.harness import run_invent


def test_the_statuses_are_their_numbers() -> None:
    assert {status.name: int(status) for status in ExitStatus} == {
        "OK": 0,
        "FAILURE": 1,
        "CONFIG": 2,
        "ABORTED": 3,
        "CANCELED": 5,
        "TIMED_OUT": 4,
        "INTERRUPTED": 130,
    }


def test_a_runs_exit_status_is_its_worst_robots_outcome_aborted_then_timed_out_then_canceled() -> None:
    assert outcome_exit_code([Outcome.COMPLETED, None]) == ExitStatus.OK, "an interrupted robot has no outcome"
    assert outcome_exit_code([Outcome.CANCELED, Outcome.COMPLETED]) == ExitStatus.CANCELED, "a goal file's last goal"
    assert outcome_exit_code([Outcome.CANCELED, Outcome.TIMED_OUT]) == ExitStatus.TIMED_OUT
    assert outcome_exit_code([Outcome.TIMED_OUT, Outcome.ABORTED, Outcome.CANCELED]) == ExitStatus.ABORTED


def test_a_bad_configuration_exits_config() -> None:
    result = run_invent("config", "--set", "motor.p_gain_l=oops")
    assert result.returncode == ExitStatus.CONFIG == 2, result.stderr
    assert "invalid configuration" in result.stderr


def test_a_good_configuration_exits_ok() -> None:
    result = run_invent("config", "--set", "motor.p_gain_l=3.0")
    assert result.returncode == ExitStatus.OK == 0, result.stderr


def test_a_call_nothing_answers_exits_failure() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    result = run_invent("call", "invent/rh0/motor/gui/stop", "--connect", endpoint, "--timeout", "0.3")
    assert result.returncode == ExitStatus.FAILURE == 1, result.stderr
    assert "invent call:" in result.stderr
