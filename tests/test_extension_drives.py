"""A service of one's own that drives (docs/extending.md, A service that drives): its core's ticks,
limits, bad input, give-up and end (services/extension/driving.py); the wanderer's deciding
(examples/services/wander.py); the loader's and ``invent up``'s refusals (exit 2 naming both)."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from examples.services.wander import SPEED, TURN_BELOW, Wanderer, room_around
from schemas.codec import BadInput
from schemas.messages import LaserScan, Time
from services.config import Config, ConfigError
from services.drive.outcome import Outcome
from services.extension.driving import FINAL_ZERO_TICKS, DrivingCore
from services.extension.loader import driving, load, load_all
from tests.harness import REPO, refused

DRIVERS = Path(__file__).parent / "data" / "extension" / "drivers.py"
WANDER = f"{REPO / 'examples' / 'services' / 'wander.py'}:Wander"
FORWARD = f"{DRIVERS}:Forward"
DRIVE = Config().drive
MS = 1_000_000
"""Nanoseconds in a millisecond: the simulator's default step."""


def _ticks(core: DrivingCore, until_ms: int, vx: float = 0.2, w: float = 0.0) -> list[tuple[int, float, float, bool]]:
    """Every step's stamp given to ``core`` up to ``until_ms``: (stamp, vx, w, final) of each tick taken."""
    taken = []
    for ms in range(until_ms + 1):
        tick = core.tick(ms * MS, vx, w)
        if tick is not None:
            taken.append((tick.stamp_ns, tick.command.vx, tick.command.w, tick.final))
    return taken


# --- the core ---


def test_the_ticks_are_the_drives_grid_each_taken_by_the_first_stamp_at_or_after_it():
    core = DrivingCore(DRIVE, 10.0)
    assert [stamp for stamp, *_ in _ticks(core, 1000)] == [k * 100 * MS for k in range(11)]
    core = DrivingCore(DRIVE, 10.0)
    stamps = [0, 30 * MS, 130 * MS, 199 * MS, 200 * MS, 450 * MS]
    taken = [stamp for stamp in stamps if core.tick(stamp, 0.0, 0.0) is not None]
    assert taken == [0, 130 * MS, 200 * MS, 450 * MS], "one stamp takes at most one tick; a gap skips ticks"


def test_commands_are_held_to_the_drives_speed_turn_rate_and_accelerations():
    core = DrivingCore(DRIVE, 10.0)
    taken = _ticks(core, 20_000, vx=5.0, w=-9.0)
    assert taken[0][1:3] == (0.0, 0.0), "from rest, no time to accelerate yet"
    assert taken[-1][1] == pytest.approx(DRIVE.cruise_speed) and taken[-1][2] == pytest.approx(-DRIVE.max_turn_rate)
    for (_, vx0, w0, _), (_, vx1, w1, _) in itertools.pairwise(taken):
        assert abs(vx1 - vx0) <= DRIVE.max_acceleration * 0.1 + 1e-12
        assert abs(w1 - w0) <= DRIVE.max_angular_acceleration * 0.1 + 1e-12


@pytest.mark.parametrize(("vx", "w"), [(math.nan, 0.0), (0.0, math.inf), (-math.inf, 0.0)])
def test_a_velocity_not_finite_is_bad_input_and_moves_nothing(vx, w):
    core = DrivingCore(DRIVE, 10.0)
    core.tick(0, 0.1, 0.0)
    with pytest.raises(BadInput, match="not finite"):
        core.tick(100 * MS, vx, w)
    assert core.commands == 1 and core.schedule.next_ns == 100 * MS, "the tick is still to take"
    assert core.tick(100 * MS, 0.1, 0.0) is not None


def test_a_motor_stopped_for_give_up_after_stop_aborts_with_final_zeros_and_the_outcome():
    core = DrivingCore(DRIVE, 10.0)
    _ticks(core, 999)
    core.give_up.motor_state("stopped", 1000 * MS, "gui")
    ended = []
    for ms in range(1000, 5000):
        tick = core.tick(ms * MS, 0.2, 0.0)
        if tick is not None and core.outcome is not None:
            ended.append(tick)
    assert DRIVE.give_up_after_stop is not None
    first = 1000 * MS + round(DRIVE.give_up_after_stop * 1e9)
    assert [tick.stamp_ns for tick in ended] == [first + k * 100 * MS for k in range(FINAL_ZERO_TICKS)]
    assert all(tick.command.vx == 0.0 and tick.command.w == 0.0 for tick in ended)
    assert [tick.final for tick in ended] == [False] * (FINAL_ZERO_TICKS - 1) + [True]
    outcome = ended[-1].outcome
    assert outcome is not None and outcome.outcome is Outcome.ABORTED and "emergency stop" in outcome.reason
    assert core.done and core.tick(10_000 * MS, 0.2, 0.0) is None, "nothing after the end"


def test_a_hold_by_the_collision_monitor_aborts_too_and_finish_completes():
    held = DrivingCore(DRIVE, 10.0)
    held.give_up.motor_state("running", 0, "", held_by="3 points in the stop zone")
    ends = [tick for tick in (held.tick(ms * MS, 0.2, 0.0) for ms in range(5000)) if tick and tick.outcome]
    assert ends[0].outcome is not None and "collision monitor" in ends[0].outcome.reason
    finished = DrivingCore(DRIVE, 10.0)
    _ticks(finished, 500)
    finished.finish("done")
    ends = [tick for tick in (finished.tick(ms * MS, 0.2, 0.0) for ms in range(501, 2000)) if tick and tick.outcome]
    assert len(ends) == 1 and ends[0].outcome is not None and ends[0].outcome.outcome is Outcome.COMPLETED


def test_a_stamp_that_goes_back_is_a_new_simulator_whose_ticks_start_over():
    core = DrivingCore(DRIVE, 10.0)
    _ticks(core, 900)
    tick = core.tick(0, 0.2, 0.0)
    assert tick is not None and tick.stamp_ns == 0 and core.restarts == 1


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.integers(1, 250),
            st.floats(-10.0, 10.0, allow_nan=False),
            st.floats(-10.0, 10.0, allow_nan=False),
        ),
        min_size=1,
        max_size=200,
    ),
    rate=st.sampled_from([5.0, 10.0, 20.0, 50.0]),
)
def test_any_inputs_give_commands_within_the_limits_one_per_tick_on_the_grid(steps, rate):
    core = DrivingCore(DRIVE, rate)
    period_ns = 1e9 / rate
    stamp, last = 0, None
    for gap_ms, vx, w in steps:
        stamp += gap_ms * MS
        tick = core.tick(stamp, vx, w)
        if tick is None:
            continue
        assert abs(tick.command.vx) <= DRIVE.cruise_speed and abs(tick.command.w) <= DRIVE.max_turn_rate
        if last is not None:
            dt = (tick.stamp_ns - last.stamp_ns) / 1e9
            assert math.floor(tick.stamp_ns / period_ns + 1e-9) > math.floor(last.stamp_ns / period_ns + 1e-9)
            assert abs(tick.command.vx - last.command.vx) <= DRIVE.max_acceleration * dt + 1e-9
            assert abs(tick.command.w - last.command.w) <= DRIVE.max_angular_acceleration * dt + 1e-9
        last = tick


# --- the wanderer's deciding ---


def _scan(hits: dict[int, float]) -> LaserScan:
    """360 rays a degree apart from -180°, ``hits`` (ray -> range) the only returns."""
    return LaserScan(
        tm=Time(sec=1, nsec=0),
        angle_min=-math.pi,
        angle_increment=math.tau / 360,
        range_min=0.12,
        range_max=3.5,
        ranges=[hits.get(index) for index in range(360)],
        bodies=[],
        hits=[],
    )


def test_the_wanderer_drives_on_a_clear_way_and_turns_towards_the_open_side_of_a_wall_ahead():
    clear = room_around(_scan({}), 0.6)
    assert (clear.ahead, clear.left, clear.right) == (3.5, 3.5, 3.5)
    wanderer = Wanderer()
    assert wanderer.command(clear) == (SPEED, 0.0)
    # a wall 1 m ahead (rays -20°..20°, index 180 is 0°), and something 0.8 m away on the right (-60°)
    wall = {180 + d: 1.0 / math.cos(math.radians(d)) for d in range(-20, 21)} | {120: 0.8}
    blocked = room_around(_scan(wall), 0.6)
    assert blocked.ahead == pytest.approx(1.0) and blocked.ahead < TURN_BELOW
    assert blocked.right == pytest.approx(0.8)
    vx, w = wanderer.command(blocked)
    assert vx == 0.0 and w > 0.0, "turns in place, to the left: more room there"
    assert wanderer.command(blocked) == (vx, w), "it keeps turning the same way until the way is clear"
    assert wanderer.command(clear)[0] == SPEED and wanderer.turns == 1


# --- declarations and refusals ---


@pytest.mark.parametrize(
    ("name", "said"),
    [
        ("DrivesInLockstep", "drives with lockstep"),
        ("DrivesAndCalls", "drives with calls"),
        ("DrivesAtNoRate", "drives.rate_hz must be"),
        ("DrivesReadingTheTruth", "reads sim/body_pose: a service that drives has the drive's rights"),
        ("DrivesTrue", "must be a Drives(rate_hz)"),
    ],
)
def test_the_loader_refuses_a_bad_drives_naming_it(name, said):
    with pytest.raises(ConfigError, match=said.replace("(", r"\(").replace(")", r"\)")):
        load(f"{DRIVERS}:{name}")


def test_one_service_drives_at_most():
    assert driving(load_all([WANDER])) is not None
    with pytest.raises(ConfigError) as refusal:
        driving(load_all([WANDER, FORWARD]))
    assert WANDER in str(refusal.value) and FORWARD in str(refusal.value)


@pytest.mark.parametrize(
    "flags",
    [
        ("--with", FORWARD),
        ("--scenario", "square"),
        ("--loop",),
        ("--goals",),
        ("--goal-file", str(REPO / "examples" / "goals" / "u_trap.toml")),
        ("--teleop", "--ros2"),
    ],
)
def test_invent_up_refuses_a_service_that_drives_beside_the_built_in_drive_naming_both(capsys, flags):
    code, _out, err = refused(capsys, "up", "--with", WANDER, *flags, "--report", "/nonexistent/never")
    assert code == 2, err
    assert "wander.py:Wander" in err
    assert flags[-1] in err if flags[0] == "--with" else flags[0] in err
