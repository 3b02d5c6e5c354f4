"""The drive's goals, pure (services/drive/goals.py, services/drive/goal_file.py): accepting and
rejecting, reaching a goal on an ideal plant, canceling, preempting, giving up, goal files."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.navigation import MAX_GOAL_SECONDS, CancelRequest, GoalRequest
from services.config import ConfigError, DriveConfig, GoalsConfig, InputConfig, NavigationConfig
from services.drive.goal_approach import Phase
from services.drive.goal_file import GoalSchedule, parse_goal_file
from services.drive.goals import MAX_ATTEMPTS, MAX_WAITING, Goals, Tick, odom_to_map
from services.drive.outcome import GiveUpRule, Outcome
from services.drive.path_following import STOPPED
from services.drive.scenarios import goal_duration
from services.navigation.costmap import Costmap
from services.navigation.grid import GridGeometry
from services.planar import Pose, wrap_angle
from tests.test_path_following import unicycle

DRIVE = DriveConfig()
GOALS = GoalsConfig()
TICK_NS = round(1e9 / DRIVE.rate)
DT = TICK_NS / 1e9
ORIGIN = Pose(0.0, 0.0, 0.0)


def make_goals(origin: Pose = ORIGIN) -> Goals:
    return Goals(DRIVE, GOALS, InputConfig(), origin)


class Plant:
    """An ideal unicycle under the goals' commands, one tick at a time."""

    def __init__(self, goals: Goals, pose: Pose = ORIGIN) -> None:
        self.goals = goals
        self.pose = pose
        self.now_ns = 0
        self.ticks: list[Tick] = []

    def tick(self) -> Tick:
        tick = self.goals.step(self.now_ns, self.pose, DT)
        self.ticks.append(tick)
        self.pose = unicycle(self.pose, tick.command, DT)
        self.now_ns += TICK_NS
        return tick

    def until_ended(self, max_ticks: int = 5000) -> list[Tick]:
        start = len(self.ticks)
        for _ in range(max_ticks):
            if self.tick().ended:
                return self.ticks[start:]
        raise AssertionError("no goal ended")

    def ended(self) -> list[tuple[str, Outcome, str]]:
        return [(e.goal.id, e.outcome, e.reason) for tick in self.ticks for e in tick.ended]


def test_a_goal_is_judged_only_once_the_pose_has_stayed_still() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=0.5, y=0.0), plant.pose, None)
    for _ in range(20_000):
        running = goals.running
        if running is not None and running.phase is Phase.SETTLE:
            break
        plant.tick()
    drift = 0
    while drift < 30:  # the body still creeping after the command is zero: not at rest yet
        plant.pose = Pose(plant.pose.x + 0.002, plant.pose.y, plant.pose.theta)
        assert not plant.tick().ended, "judged while the pose still moved"
        drift += 1
    ticks = plant.until_ended()
    assert len(ticks) >= round(0.2 * DRIVE.rate), "still for SETTLE_S before it is judged"
    assert plant.ended()[-1][1] is Outcome.COMPLETED


def test_a_goal_is_reached_within_its_tolerances_and_ends_completed_at_rest() -> None:
    goals = make_goals()
    plant = Plant(goals)
    reply = goals.send(GoalRequest(x=1.5, y=0.5, theta=1.57), plant.pose, None)
    assert reply.accepted and reply.id == "g1"
    ticks = plant.until_ended()
    assert ticks[0].started is not None and ticks[0].started.goal.id == "g1"
    assert plant.ended() == [("g1", Outcome.COMPLETED, "")]
    assert math.hypot(plant.pose.x - 1.5, plant.pose.y - 0.5) <= GOALS.position_tolerance
    assert abs(wrap_angle(plant.pose.theta - 1.57)) <= GOALS.heading_tolerance
    assert ticks[-1].command == STOPPED
    assert goals.idle and goals.counts["completed"] == 1


@settings(max_examples=25, deadline=None)
@given(
    st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0),
    st.one_of(st.none(), st.floats(-math.pi, math.pi)),
    st.floats(-math.pi, math.pi),
)
def test_any_goal_in_reach_is_completed_within_its_tolerances(x: float, y: float, theta, start_theta: float) -> None:
    goals = make_goals()
    plant = Plant(goals, Pose(0.0, 0.0, start_theta))
    assert goals.send(GoalRequest(x=x, y=y, theta=theta), plant.pose, None).accepted
    plant.until_ended(max_ticks=20_000)
    [(_, outcome, reason)] = plant.ended()
    assert outcome is Outcome.COMPLETED, reason
    assert math.hypot(plant.pose.x - x, plant.pose.y - y) <= GOALS.position_tolerance
    if theta is not None:
        assert abs(wrap_angle(plant.pose.theta - theta)) <= GOALS.heading_tolerance


def test_the_commands_to_a_goal_respect_the_drives_acceleration_limits() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=1.0, y=-1.0, theta=3.0), plant.pose, None)
    ticks = plant.until_ended()
    previous = STOPPED
    for tick in ticks:
        assert abs(tick.command.vx - previous.vx) <= DRIVE.max_acceleration * DT + 1e-12
        assert abs(tick.command.w - previous.w) <= DRIVE.max_angular_acceleration * DT + 1e-12
        previous = tick.command


def test_a_canceled_goal_brakes_to_a_stop_then_ends_canceled() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=3.0, y=0.0), plant.pose, None)
    for _ in range(150):  # 3 s: well under way
        plant.tick()
    moving = goals.command
    assert moving.vx > 0.2
    reply = goals.cancel(CancelRequest())
    assert reply.canceling == ["g1"] and reply.reason == ""
    ticks = plant.until_ended()
    speeds = [tick.command.vx for tick in ticks]
    assert speeds == sorted(speeds, reverse=True), "braking only"
    assert len(ticks) >= moving.vx / DRIVE.max_acceleration / DT - 1, "at the drive's deceleration, not at once"
    assert ticks[-1].command == STOPPED
    [(goal_id, outcome, reason)] = plant.ended()
    assert (goal_id, outcome, reason) == ("g1", Outcome.CANCELED, "canceled")
    assert goals.counts["canceled"] == 1
    assert plant.pose.x < 3.0 - GOALS.position_tolerance


def test_a_new_goal_preempts_the_running_one_which_ends_canceled_without_a_stop() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=3.0, y=0.0), plant.pose, None)
    for _ in range(100):
        plant.tick()
    before = goals.command
    assert goals.send(GoalRequest(x=2.0, y=1.0, id="second"), plant.pose, None).accepted
    tick = plant.tick()
    assert [(e.goal.id, e.outcome, e.reason) for e in tick.ended] == [
        ("g1", Outcome.CANCELED, "preempted by goal 'second'")
    ]
    assert tick.started is not None and tick.started.goal.id == "second"
    assert tick.command.vx >= before.vx - DRIVE.max_acceleration * DT - 1e-12, "no stop in between"
    plant.until_ended()
    assert plant.ended()[-1][:2] == ("second", Outcome.COMPLETED)


def test_two_goals_sent_between_ticks_the_first_never_starts_and_ends_canceled() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=1.0, y=0.0), plant.pose, None)
    goals.send(GoalRequest(x=0.0, y=1.0), plant.pose, None)
    tick = plant.tick()
    assert [(e.goal.id, e.outcome) for e in tick.ended] == [("g1", Outcome.CANCELED)]
    assert "before it started" in tick.ended[0].reason
    assert tick.started is not None and tick.started.goal.id == "g2"


@pytest.mark.parametrize(
    ("request_", "reason"),
    [
        (GoalRequest(x=math.nan, y=0.0), "`x` must be finite"),
        (GoalRequest(x=1.0, y=math.inf), "`y` must be finite"),
        (GoalRequest(x=1.0, y=0.0, theta=math.nan), "`theta` must be finite"),
        (GoalRequest(x=1.0, y=0.0, position_tolerance=0.0), "`position_tolerance` must be > 0"),
        (GoalRequest(x=1.0, y=0.0, heading_tolerance=-0.1), "`heading_tolerance` must be > 0"),
        (GoalRequest(x=1.0, y=0.0, time_limit=0.0), "`time_limit` must be > 0"),
        (GoalRequest(x=1.0, y=0.0, time_limit=1e308), "`time_limit` must be at most 1e+09 s, got 1e+308"),
        (GoalRequest(x=1.0, y=0.0, time_limit=MAX_GOAL_SECONDS * 1.001), "`time_limit` must be at most 1e+09 s"),
        (GoalRequest(x=1.0, y=0.0, frame="base_link"), "unknown frame 'base_link'"),
        (GoalRequest(x=2e4, y=0.0), "beyond input.max_coordinate"),
        (GoalRequest(x=500.0, y=0.0), "beyond goals.max_distance"),
        (GoalRequest(x=1.0, y=0.0, id="g1"), "'g1' is still running"),
    ],
)
def test_a_bad_goal_is_rejected_with_its_reason_and_the_running_goal_goes_on(request_, reason) -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=2.0, y=0.0), plant.pose, None)
    for _ in range(50):
        plant.tick()
    before = (goals.running, goals.command)
    reply = goals.send(request_, plant.pose, None)
    assert not reply.accepted and reply.id == ""
    assert reason in reply.reason
    assert goals.counts["rejected"] == 1 and goals.pending is None
    assert (goals.running, goals.command) == before
    tick = plant.tick()
    assert not tick.ended and tick.started is None


def test_a_flood_of_goals_between_two_ticks_is_bounded_and_the_last_accepted_one_starts() -> None:
    goals = make_goals()
    replies = [goals.send(GoalRequest(x=1.0, y=float(k) / 100), ORIGIN, None) for k in range(MAX_WAITING + 5)]
    accepted = [reply.id for reply in replies if reply.accepted]
    assert len(accepted) == MAX_WAITING + 1, "one to start, the ones it replaced waiting to end canceled"
    assert all("wait for the drive's next tick" in reply.reason for reply in replies if not reply.accepted)
    tick = goals.step(0, ORIGIN, 0.0)
    assert [e.goal.id for e in tick.ended] == accepted[:-1] and {e.outcome for e in tick.ended} == {Outcome.CANCELED}
    assert tick.started is not None and tick.started.goal.id == accepted[-1]
    assert goals.send(GoalRequest(x=1.0, y=0.0), ORIGIN, None).accepted, "room again once the tick came"


def test_a_goal_is_rejected_while_the_motor_is_latched_stopped_or_no_pose_is_known() -> None:
    goals = make_goals()
    stopped = goals.send(GoalRequest(x=1.0, y=0.0), ORIGIN, "bump")
    assert not stopped.accepted and "latched stopped (by bump)" in stopped.reason and "clear" in stopped.reason
    blind = goals.send(GoalRequest(x=1.0, y=0.0), None, None)
    assert not blind.accepted and "no pose" in blind.reason
    assert goals.counts["rejected"] == 2 and goals.idle


def test_cancels_of_nothing_of_an_unknown_id_or_of_an_ended_goal_are_refused_and_counted() -> None:
    goals = make_goals()
    plant = Plant(goals)
    assert goals.cancel(CancelRequest()).reason == "no goal runs"
    goals.send(GoalRequest(x=0.5, y=0.0), plant.pose, None)
    assert goals.cancel(CancelRequest("nope")).reason == "unknown goal id 'nope'"
    plant.until_ended()
    refused = goals.cancel(CancelRequest("g1"))
    assert refused.canceling == [] and refused.reason == "goal 'g1' already ended: completed"
    assert goals.counts["cancel_rejected"] == 3


def test_a_goal_in_odom_is_turned_into_map_by_the_robots_initial_pose() -> None:
    origin = Pose(1.0, 2.0, math.pi / 2)
    assert odom_to_map(origin, 1.0, 0.0, 0.0) == pytest.approx((1.0, 3.0, math.pi / 2))
    goals = make_goals(origin)
    plant = Plant(goals, origin)
    goals.send(GoalRequest(x=0.5, y=0.0, theta=0.0, frame="odom"), plant.pose, None)
    tick = plant.tick()
    assert tick.started is not None
    started = tick.started.goal
    assert (started.x, started.y, started.theta) == pytest.approx((1.0, 2.5, math.pi / 2))
    assert started.frame == "odom"


def test_a_goal_given_up_ends_with_that_outcome_and_the_command_is_zero_at_once() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=2.0, y=0.0), plant.pose, None)
    for _ in range(100):
        plant.tick()
    ended = goals.give_up(plant.now_ns, Outcome.ABORTED, "held by the collision monitor")
    assert ended is not None and (ended.goal.id, ended.outcome) == ("g1", Outcome.ABORTED)
    assert ended.elapsed_s == pytest.approx(100 * DT)
    assert goals.command == STOPPED and goals.idle
    assert plant.tick().command == STOPPED


def test_a_robot_pushed_off_its_goal_at_rest_drives_again_and_gives_up_after_the_last_attempt() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=1.0, y=0.0), plant.pose, None)
    pushed: set[int] = set()
    for _ in range(20_000):
        running = goals.running
        if running is not None and running.phase is Phase.SETTLE and running.attempts not in pushed:
            plant.pose = Pose(plant.pose.x - 0.2, plant.pose.y, plant.pose.theta)  # pushed back as it settles
            pushed.add(running.attempts)
        if plant.tick().ended:
            break
    [(_, outcome, reason)] = plant.ended()
    assert outcome is Outcome.ABORTED
    assert f"after {MAX_ATTEMPTS} approaches" in reason
    assert pushed == set(range(1, MAX_ATTEMPTS + 1)), "pushed once in each approach's settling"


def test_the_time_limit_of_a_goal_is_its_own_or_the_drives_rule_from_where_it_starts() -> None:
    goals = make_goals()
    goals.send(GoalRequest(x=3.0, y=0.0, time_limit=7.5), ORIGIN, None)
    own = goals.step(0, ORIGIN, 0.0).started
    assert own is not None and own.time_limit_s == 7.5
    goals.send(GoalRequest(x=3.0, y=0.0), ORIGIN, None)
    ruled = goals.step(TICK_NS, ORIGIN, DT).started
    assert ruled is not None
    planned = goal_duration(ORIGIN, 3.0, 0.0, None, DRIVE)
    assert planned == pytest.approx(3.0 / DRIVE.cruise_speed + DRIVE.cruise_speed / DRIVE.max_acceleration)
    assert DRIVE.time_limit_factor is not None
    assert ruled.time_limit_s == pytest.approx(DRIVE.time_limit_factor * planned + DRIVE.time_limit_margin)


def test_a_goal_with_the_longest_time_limit_starts_and_the_drives_rule_takes_it() -> None:
    """The bound is where the goal enters: at it, the limit converts to nanoseconds and the goal runs."""
    goals = make_goals()
    plant = Plant(goals)
    assert goals.send(GoalRequest(x=1.0, y=0.0, time_limit=MAX_GOAL_SECONDS), plant.pose, None).accepted
    started = plant.tick().started
    assert started is not None and started.time_limit_s == MAX_GOAL_SECONDS
    rule = GiveUpRule(DRIVE, None)
    rule.limit(started.time_limit_s)
    assert rule.check(TICK_NS, round(MAX_GOAL_SECONDS * 1e9)) is None
    assert rule.check(TICK_NS, round(MAX_GOAL_SECONDS * 1e9) + 1) is not None


def test_the_feedback_counts_the_distance_down_and_the_estimate_shrinks() -> None:
    goals = make_goals()
    plant = Plant(goals)
    goals.send(GoalRequest(x=2.0, y=0.0), plant.pose, None)
    seen = []
    for _ in range(400):
        plant.tick()
        progress = goals.progress(plant.now_ns, plant.pose)
        if progress is None:
            break
        seen.append(progress)
    assert seen[0].distance_remaining == pytest.approx(2.0, abs=0.01)
    distances = [p.distance_remaining for p in seen]
    assert distances == sorted(distances, reverse=True)
    assert seen[-1].estimated_remaining_s < seen[0].estimated_remaining_s
    assert [p.elapsed_s for p in seen] == sorted(p.elapsed_s for p in seen)


GOAL_FILE = """
name = "errands"

[[goals]]
at = 0.0
x = 1.5
y = 0.5
theta = 1.57

[[goals]]
at = 4.0
cancel = true

[[goals]]
at = 4.0
x = 0.0
y = 0.0
id = "home"
"""


def test_a_goal_file_sends_each_entry_at_the_first_tick_at_or_after_its_time() -> None:
    schedule = GoalSchedule(parse_goal_file(GOAL_FILE))
    assert [entry.x for entry in schedule.due(0)] == [1.5]
    assert schedule.due(3_999_999_999) == []
    due = schedule.due(4_000_000_000)
    assert [entry.request() for entry in due] == [CancelRequest(), GoalRequest(x=0.0, y=0.0, id="home")]
    assert schedule.exhausted


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[goals]]\nat = 1.0\nx = 1.0\ny = 0.0\n[[goals]]\nat = 0.5\ncancel = true\n", "before the entry above"),
        ("[[goals]]\nat = 0.0\ncancel = true\nx = 1.0\n", "a cancel takes only"),
        ("[[goals]]\nat = 0.0\nx = 1.0\n", "needs `x` and `y`"),
        ("[[goals]]\nat = 0.0\nx = 1.0\ny = 0.0\nspeed = 2\n", "unknown field `speed`"),
        ("[[goals]]\nat = -1.0\nx = 1.0\ny = 0.0\n", "goals[0].at"),
        ("[[goals]]\nat = 1e308\nx = 1.0\ny = 0.0\n", "<= 1000000000.0 - at `goals[0].at`"),
        ("[[goals]]\nat = 0.0\nx = 1.0\ny = 0.0\ntime_limit = 1e308\n", "<= 1000000000.0 - at `goals[0].time_limit`"),
        ("goals = []\n", "goals"),
    ],
)
def test_a_bad_goal_file_is_a_configuration_error_naming_the_entry(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match="goal file") as error:
        parse_goal_file(text)
    assert message in str(error.value)


def test_a_goal_off_the_costmap_is_rejected_naming_its_extent_while_goals_navigate() -> None:
    navigation = NavigationConfig()
    costmap = Costmap(GridGeometry.centred(0.0, 0.0, 4.0, 0.05), navigation, 0.45)
    goals = Goals(DRIVE, GOALS, InputConfig(), ORIGIN, costmap, navigation)
    reply = goals.send(GoalRequest(x=3.0, y=0.0), ORIGIN, None)
    assert not reply.accepted and "off the costmap (x -2.00 to 2.00, y -2.00 to 2.00)" in reply.reason, reply
    assert goals.send(GoalRequest(x=1.5, y=0.0), ORIGIN, None).accepted
