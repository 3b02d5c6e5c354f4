"""The restart policy's core (services/launch/restart.py): which exits are failures, the limit, the
backoff schedule (Docker's: doubling from the first delay, capped, back to the first after a stable
run), the services never restarted; and ``invent up``'s refusals of its flags (exit 2 naming the
flag). No zenoh, no processes."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.config import ConfigError
from services.exits import ExitStatus
from services.launch.restart import (
    MAX_DELAY_S,
    STABLE_AFTER_S,
    History,
    RestartPlan,
    RestartPolicy,
    RestartRule,
    parse_restarts,
)
from tests.harness import refused

ON_FAILURE = RestartPolicy.ON_FAILURE
SIGKILL = -9


def schedule(rule: RestartRule, ran_s: list[float], exit_code: int = SIGKILL) -> list[float]:
    """The delays before each restart of a service that failed after running each of ``ran_s`` in
    turn, until it is not started again."""
    history, delays = History(), []
    for ran in ran_s:
        following = rule.next_restart(history, exit_code, ran)
        if following is None:
            break
        assert following.restarts == history.restarts + 1
        history = following
        delays.append(history.delay_s)
    return delays


limits = st.integers(min_value=1, max_value=20)
first_delays = st.floats(min_value=0.001, max_value=MAX_DELAY_S)
quick_failures = st.lists(st.floats(min_value=0.0, max_value=STABLE_AFTER_S, exclude_max=True), max_size=40)


@given(limits, first_delays, quick_failures)
def test_failures_in_a_row_double_the_delay_up_to_the_cap_and_stop_at_the_limit(
    limit: int, first_s: float, ran_s: list[float]
) -> None:
    delays = schedule(RestartRule(ON_FAILURE, limit, first_s), ran_s)
    assert len(delays) == min(limit, len(ran_s)), "every failure restarted until the limit, none past it"
    expected = [min(first_s * 2**index, MAX_DELAY_S) for index in range(len(delays))]
    assert delays == pytest.approx(expected)
    assert all(delay <= MAX_DELAY_S for delay in delays)


@given(limits, first_delays, st.lists(st.floats(min_value=0.0, max_value=3 * STABLE_AFTER_S), max_size=40))
def test_a_stable_run_starts_the_delays_over_and_the_limit_counts_every_restart(
    limit: int, first_s: float, ran_s: list[float]
) -> None:
    delays = schedule(RestartRule(ON_FAILURE, limit, first_s), ran_s)
    assert len(delays) == min(limit, len(ran_s)), "the limit counts restarts in the run, not in a row"
    for index, delay in enumerate(delays):
        if index == 0 or ran_s[index] >= STABLE_AFTER_S:
            assert delay == first_s
        else:
            assert delay == pytest.approx(min(delays[index - 1] * 2, MAX_DELAY_S))


@given(st.sampled_from([0, ExitStatus.CONFIG]), st.floats(min_value=0, max_value=100))
def test_a_clean_exit_and_a_refused_configuration_are_not_failures(exit_code: int, ran_s: float) -> None:
    assert RestartRule(ON_FAILURE).next_restart(History(), exit_code, ran_s) is None


def test_a_service_made_never_is_not_restarted_and_asking_for_it_is_refused_naming_why() -> None:
    plan = RestartPlan(ON_FAILURE).never({"drive"}, "the sim ends the run")
    assert plan.rule("drive").policy is RestartPolicy.NEVER and plan.rule("rh0/drive").policy is RestartPolicy.NEVER
    assert plan.rule("motor").policy is ON_FAILURE
    asked = RestartPlan(*parse_restarts(["drive=on-failure"]))
    with pytest.raises(ConfigError, match="--restart drive=on-failure: the sim ends the run"):
        asked.never({"drive"}, "the sim ends the run")


@given(st.integers(min_value=-64, max_value=255).filter(lambda code: code not in (0, ExitStatus.CONFIG)))
def test_never_restarts_nothing_and_on_failure_every_failure(exit_code: int) -> None:
    assert RestartRule(RestartPolicy.NEVER).next_restart(History(), exit_code, 1.0) is None
    assert RestartRule(ON_FAILURE).next_restart(History(), exit_code, 1.0) is not None


def test_a_services_own_policy_wins_over_every_services_and_applies_to_each_robot_of_a_fleet() -> None:
    default, by_service = parse_restarts(["on-failure", "odometry=never", "motor=on-failure"])
    plan = RestartPlan(default, by_service)
    assert plan.rule("sim").policy is ON_FAILURE
    assert plan.rule("odometry").policy is RestartPolicy.NEVER
    assert plan.rule("rh1/odometry").policy is RestartPolicy.NEVER
    only_motor = RestartPlan(*parse_restarts(["motor=on-failure"]))
    assert (only_motor.rule("rh0/motor").policy, only_motor.rule("sim").policy) == (ON_FAILURE, RestartPolicy.NEVER)
    assert RestartPlan().restarts_any is False and only_motor.restarts_any is True


@pytest.mark.parametrize("spec", ["always", "motor=sometimes", "=on-failure", "motor="])
def test_a_policy_that_is_neither_is_refused_naming_it(spec: str) -> None:
    with pytest.raises(ConfigError, match=f"--restart {spec}:"):
        parse_restarts([spec])


def test_a_service_of_no_run_and_bad_bounds_are_refused_naming_them() -> None:
    with pytest.raises(ConfigError, match="--restart motr=on-failure: no such service"):
        RestartPlan(*parse_restarts(["motr=on-failure"])).check_services({"motor", "sim"})
    with pytest.raises(ConfigError, match="--restart-limit 0"):
        RestartPlan(limit=0)
    with pytest.raises(ConfigError, match="--restart-backoff"):
        RestartPlan(first_delay_s=MAX_DELAY_S + 1)


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("--restart", "on-failure", "--composed"), "--restart with --composed"),
        (("--restart", "sometimes"), "--restart sometimes"),
        (("--restart", "motr=on-failure"), "--restart motr=on-failure"),
        (("--restart", "drive=on-failure"), "--restart drive=on-failure"),
        (("--restart", "on-failure", "--restart-limit", "0"), "--restart-limit"),
        (("--restart", "on-failure", "--restart-backoff", "nan"), "--restart-backoff"),
    ],
)
def test_invent_up_refuses_what_it_cannot_restart_with_exit_2_naming_the_flag(
    capsys: pytest.CaptureFixture[str], args: tuple[str, ...], named: str
) -> None:
    code, out, err = refused(capsys, "up", "--engine", "kinematic", "--no-record", *args)
    assert code == ExitStatus.CONFIG, out + err
    assert named in out + err
