"""What ``make soak-day`` judges a day by (benchmarks/day_memory.py, hostile_bursts.py), on made-up
samples: which cancels it must not send as hostile (they cancel a running errand), from when a process's memory counts
(after its last start and past the first burst's high water), the step each burst leaves, and the
growth per simulated hour."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.day_memory import growth, past_high_water, steps_at_bursts
from benchmarks.hostile_bursts import cancels_whatever_runs
from benchmarks.soak_day import Day


@pytest.mark.parametrize("payload", [b"", b"  ", b"{}", b"{ }", b'{"id": ""}', b'{"id":""}', b' {"id" : ""} '])
def test_a_cancel_with_no_id_however_spelled_cancels_whatever_runs(payload):
    assert cancels_whatever_runs(payload)


@pytest.mark.parametrize("payload", [b'{"id": "x"}', b"{", b"\xff", b'{"id": 1}', b'{"id": "", "x": 1}', b"[]"])
def test_a_cancel_naming_a_goal_or_that_does_not_decode_is_refused_whatever_runs(payload):
    assert not cancels_whatever_runs(payload)


FAULTS = [
    {"kind": "hostile", "at_sim_h": 2.5, "done_at_sim_h": 2.52},
    {"kind": "service", "at_sim_h": 3.0, "done_at_sim_h": 3.0},
    {"kind": "router", "at_sim_h": 6.0, "done_at_sim_h": 6.0},
    {"kind": "hostile", "at_sim_h": 8.5, "done_at_sim_h": 8.51},
    {"kind": "service", "at_sim_h": 9.0, "done_at_sim_h": 9.0},
]


def test_memory_counts_past_the_first_burst_since_the_processs_last_start():
    assert past_high_water(FAULTS, None, 1.0) == 2.52, "up: started once, its first burst at 2.5 h"
    assert past_high_water(FAULTS, "router", 1.0) == 8.51, "the router: started again at 6 h, a burst at 8.5 h"
    assert past_high_water(FAULTS, "service", 1.0) == 9.0, "the ledger: started again at 9 h, no burst since"
    assert past_high_water([], None, 1.0) == 1.0, "no fault: after the warm-up"


def _sample(sim_h: float, up: float, router: float | None) -> dict:
    return {"sim_h": sim_h, "rss_mb": {"up": up, "router": router, "fixes": None}}


def test_a_bursts_step_is_the_memory_just_after_it_less_just_before():
    samples = [
        _sample(2.4, 100.0, 38.0),
        _sample(2.49, 101.0, 38.0),
        _sample(2.6, 123.0, 74.0),
        _sample(8.6, 124.0, 58.0),
    ]
    steps = steps_at_bursts(samples, FAULTS)
    assert steps == [
        {"at_sim_h": 2.5, "mb": {"up": 22.0, "router": 36.0}},
        {"at_sim_h": 8.5, "mb": {"up": 1.0, "router": -16.0}},
    ]


def test_growth_is_the_slope_in_mb_per_simulated_hour_from_the_hour_given():
    samples = [_sample(h, 100.0 + (30.0 if h >= 2.5 else 0.0) + 0.5 * h, 38.0) for h in (1.0, 2.0, 3.0, 4.0, 5.0)]
    assert growth(samples, "up", 2.52) == pytest.approx(0.5), "past the step: the leak, if any"
    assert growth(samples, "up", 1.0) > 1.0, "with the step: more than the bound"
    assert growth(samples, "fixes", 1.0) is None, "never sampled"


def test_a_goals_end_glued_after_a_progress_line_is_read_and_both_figures_kept():
    """Up's progress line and a service's log line can share a line of up's output; a day read 719
    of 720 goals' ends when a progress line hid one."""
    day = Day(endpoint="tcp/127.0.0.1:1", report_dir=Path("run"), router=None, bursts=[])
    day.read_line(
        "[up          ] sim 3600.00 s | 17.10x real time | pose x +0.000 y +0.000 theta +0.000"
        "14:06:44.077 INFO    invent.drive: goal 'errand_7' completed after 12.340 s\n"
    )
    day.read_line("14:06:45.000 WARNING invent.drive: goal 'errand_8' aborted after 3.000 s: blocked\n")
    day.read_line(
        "[up          ] started fixes (pid 42)14:07 INFO invent.drive: goal 'errand_9' completed after 1.0 s\n"
    )
    assert day.sim_s == 3600.0
    assert day.outcomes == {"completed": ["errand_7", "errand_9"], "aborted": ["errand_8"]}
    assert day.beside_pids == [42]
