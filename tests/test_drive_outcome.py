"""How a scenario ends (services/drive/outcome.py), pure: the time limit from the plan, and when the
drive gives up on a latched stop or a pass that lasts too long, with a reason naming the cause."""

from __future__ import annotations

import math

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.navigation import MAX_GOAL_SECONDS
from services.config import ConfigError, DriveConfig
from services.drive.outcome import EXIT_CODES, OUTCOME_OF_EXIT_CODE, GiveUpRule, Outcome, time_limit
from services.drive.path_following import STOPPED
from services.drive.scenarios import (
    BUILTIN_SCENARIOS,
    ConstantSegment,
    Scenario,
    ScenarioRunner,
    parse_scenario,
    planned_duration,
)
from services.planar import Pose

ORIGIN = Pose(0.0, 0.0, 0.0)
PARAMS = DriveConfig()
NS = 1_000_000_000


def test_the_outcomes_have_four_distinct_exit_codes_zero_for_completed() -> None:
    assert EXIT_CODES == {Outcome.COMPLETED: 0, Outcome.ABORTED: 3, Outcome.TIMED_OUT: 4, Outcome.CANCELED: 5}
    assert {OUTCOME_OF_EXIT_CODE[outcome.exit_code] for outcome in Outcome} == set(Outcome)


def test_the_planned_duration_of_the_square_is_its_legs_at_cruise_speed_and_its_three_turns_in_place() -> None:
    leg = 1.0 / PARAMS.cruise_speed + PARAMS.cruise_speed / PARAMS.max_acceleration
    turns = 3 * (math.pi / 2) / PARAMS.max_turn_rate
    assert planned_duration(BUILTIN_SCENARIOS["square"], ORIGIN, PARAMS) == pytest.approx(4 * leg + turns)


def test_the_planned_duration_of_constant_segments_is_their_durations() -> None:
    circle = BUILTIN_SCENARIOS["figure8"]
    assert planned_duration(circle, ORIGIN, PARAMS) == pytest.approx(sum(s.duration for s in circle.segments))


def test_the_default_time_limit_is_three_times_the_plan_and_ten_seconds_and_a_file_may_set_its_own() -> None:
    straight = BUILTIN_SCENARIOS["straight"]
    planned = planned_duration(straight, ORIGIN, PARAMS)
    assert time_limit(straight, ORIGIN, PARAMS) == pytest.approx(3 * planned + 10)
    own = msgspec.structs.replace(straight, time_limit=5.0)
    assert time_limit(own, ORIGIN, PARAMS) == 5.0
    assert time_limit(straight, ORIGIN, msgspec.structs.replace(PARAMS, time_limit_factor=None)) is None


SCENARIO_FILE = """time_limit = {limit}
[[segments]]
type = "constant"
vx = 0.1
w = 0.0
duration = {duration}
"""


@pytest.mark.parametrize(("limit", "duration", "field"), [(1e308, 1.0, "time_limit"), (1.0, 1e308, "duration")])
def test_a_scenario_file_whose_seconds_overflow_nanoseconds_is_a_configuration_error_naming_the_field(
    limit: float, duration: float, field: str
) -> None:
    """1e308 s overflowed the drive's conversion to nanoseconds as it started (an OverflowError)."""
    with pytest.raises(ConfigError, match=f"<= 1000000000.0 - at `.*{field}`"):
        parse_scenario(SCENARIO_FILE.format(limit=limit, duration=duration))


def test_the_longest_time_limit_a_scenario_or_goal_may_say_converts_to_nanoseconds() -> None:
    scenario = parse_scenario(SCENARIO_FILE.format(limit=MAX_GOAL_SECONDS, duration=MAX_GOAL_SECONDS))
    rule = GiveUpRule(DriveConfig(), time_limit(scenario, Pose(0.0, 0.0, 0.0), DriveConfig()))
    assert rule.check(0, round(MAX_GOAL_SECONDS * 1e9)) is None
    assert rule.check(0, round(MAX_GOAL_SECONDS * 1e9) + 1) is not None


def test_a_motor_stopped_by_a_bump_is_given_up_after_the_configured_time_naming_the_obstacle() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.bump("box", int(1.872 * NS))
    rule.motor_state("stopped", int(1.876 * NS), "bump")  # the motor latches a few steps after the contact
    assert rule.check(int(3.872 * NS) - 1, 0) is None, "not before give_up_after_stop"
    given_up = rule.check(int(3.872 * NS), 0)
    assert given_up is not None and given_up.outcome is Outcome.ABORTED, "timed from the contact, not the latch"
    assert "bumped into 'box' at t = 1.872 s" in given_up.reason and "stayed stopped for 2.000 s" in given_up.reason


def test_a_bump_long_before_a_stop_by_bump_is_not_named_as_its_cause() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.bump("wall", 1 * NS)
    rule.motor_state("stopped", 5 * NS, "bump")
    given_up = rule.check(7 * NS, 0)
    assert given_up is not None and given_up.reason.startswith("a bump:") and "wall" not in given_up.reason


def test_an_emergency_stop_is_named_and_a_clear_in_time_gives_nothing_up() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.motor_state("stopped", 1 * NS, "gui")
    rule.motor_state("running", 2 * NS, "")
    assert rule.check(10 * NS, 10 * NS) is None, "cleared after 1 s: goes on"
    rule.motor_state("stopped", 11 * NS, "gui")
    given_up = rule.check(14 * NS, 14 * NS)
    assert given_up is not None and given_up.reason.startswith("an emergency stop (motor/gui/stop)")


HELD_BY = "obstacle 'box' in the stop zone, 0.31 m ahead at (0.76, 0.02) in base_link"


def test_a_robot_held_by_the_collision_monitor_is_given_up_after_the_configured_time_naming_the_obstacle() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.motor_state("running", int(1.5 * NS), "", HELD_BY)
    assert rule.check(int(3.5 * NS) - 1, 0) is None, "not before give_up_after_stop"
    given_up = rule.check(int(3.5 * NS), 0)
    assert given_up is not None and given_up.outcome is Outcome.ABORTED
    assert given_up.reason == f"held by the collision monitor for 2.000 s since t = 1.500 s: {HELD_BY}"


def test_a_hold_that_ends_in_time_gives_nothing_up_and_a_change_of_cause_goes_on() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.motor_state("running", 1 * NS, "", HELD_BY)
    rule.motor_state("running", 2 * NS, "", "")
    assert rule.check(int(3.5 * NS), 0) is None, "released after 1 s"
    rule.motor_state("running", 4 * NS, "", HELD_BY)
    stale = "no scan for 0.52 s (collision_monitor.scan_timeout 0.5 s)"
    rule.motor_state("running", 5 * NS, "", stale)
    given_up = rule.check(6 * NS, 0)
    assert given_up is not None and given_up.reason.endswith(f"for 2.000 s since t = 4.000 s: {stale}")


def test_a_hold_is_not_given_up_when_the_rule_is_off_nor_across_a_new_time_base() -> None:
    off = GiveUpRule(msgspec.structs.replace(PARAMS, give_up_after_stop=None), limit_s=None)
    off.motor_state("running", 0, "", HELD_BY)
    assert off.check(10**15, 0) is None
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.motor_state("running", 9 * NS, "", HELD_BY)
    rule.restart(0)
    assert rule.check(3 * NS, 0) is None and rule.held_by == ""


def test_a_pass_past_its_time_limit_times_out_and_never_before() -> None:
    rule = GiveUpRule(PARAMS, limit_s=8.5)
    assert rule.check(100 * NS, int(8.5 * NS)) is None
    given_up = rule.check(100 * NS, int(8.5 * NS) + 1)
    assert given_up is not None and given_up.outcome is Outcome.TIMED_OUT and "time limit of 8.500 s" in given_up.reason


@given(
    stopped_at=st.integers(min_value=0, max_value=10**12),
    held=st.integers(min_value=0, max_value=10**10),
    give_up_after=st.floats(min_value=0.001, max_value=9.0),
)
def test_a_stop_is_given_up_exactly_when_it_has_held_for_give_up_after_stop(
    stopped_at: int, held: int, give_up_after: float
) -> None:
    rule = GiveUpRule(msgspec.structs.replace(PARAMS, give_up_after_stop=give_up_after), limit_s=None)
    rule.motor_state("stopped", stopped_at, "bump")
    rule.motor_state("stopped", stopped_at + held // 2, "bump")  # a repeated report does not restart it
    given_up = rule.check(stopped_at + held, 0)
    assert (given_up is not None) == (held >= round(give_up_after * NS))


def test_no_give_up_when_both_rules_are_off() -> None:
    rule = GiveUpRule(msgspec.structs.replace(PARAMS, give_up_after_stop=None), limit_s=None)
    rule.motor_state("stopped", 0, "bump")
    assert rule.check(10**15, 10**15) is None


def test_a_looping_scenario_times_each_pass_from_its_own_start() -> None:
    one_second = Scenario(name="s", segments=[ConstantSegment(vx=0.1, w=0.0, duration=1.0)])
    runner = ScenarioRunner(one_second, PARAMS, loop=True)
    tick = NS // 50
    for step in range(251):
        runner.step(step * tick, ORIGIN)
    assert runner.iteration == 5 and runner.pass_elapsed_ns == 0, "the sixth pass begins at 5 s"
    runner.step(251 * tick, ORIGIN)
    assert runner.pass_elapsed_ns == tick
    runner.give_up()
    assert runner.done and runner.step(252 * tick, ORIGIN) == STOPPED


def test_the_bump_that_latched_the_stop_is_named_not_a_later_touch_while_stopped() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.motor_state("stopped", int(1.871 * NS), "bump")  # the motor's stamp a step before the contact's
    rule.bump("box", int(1.872 * NS))
    rule.bump("box", int(3.763 * NS))  # pushed back against the box, stopped
    given_up = rule.check(int(3.872 * NS), 0)
    assert given_up is not None and given_up.reason.startswith("bumped into 'box' at t = 1.872 s")


def test_a_stop_still_latched_after_a_simulator_restart_counts_from_the_new_time_base() -> None:
    rule = GiveUpRule(PARAMS, limit_s=None)
    rule.bump("box", 50 * NS)
    rule.motor_state("stopped", 50 * NS, "bump")
    rule.restart(0)  # a new simulator: its clock starts again at 0
    assert rule.check(1 * NS, 0) is None, "not judged against the old time base"
    given_up = rule.check(2 * NS, 0)
    assert given_up is not None and given_up.reason.startswith("a bump:"), "the old contact is not named"
