"""``python -m benchmarks --quick`` runs every section and writes the result fields (no speed asserted)."""

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import fleet, lateness, localization, navigation
from benchmarks.run import RESULTS
from tests.harness import REPO

pytestmark = pytest.mark.slow

NUMBERS = (
    "lockstep.steps_per_s",
    "lockstep.inprocess_steps_per_s",
    "lockstep.ratio",
    "lockstep.floor_round_trips_per_s",
    "lockstep.floor_ratio",
    "lockstep.up_steps_per_s",
    "lockstep.up_not_recording_steps_per_s",
    "lockstep.lowlatency_steps_per_s",
    "lockstep.composed_steps_per_s",
    "lockstep.composed_ratio",
    "lockstep.composed_recording_steps_per_s",
    "lockstep.composed_no_intra_process_steps_per_s",
    "lockstep.rt_steps_per_s",
    "lockstep.rt_floor_ratio",
    "lockstep.cpu_us_per_step.rt",
    "lockstep.composed_rt_steps_per_s",
    "lockstep.composed_rt_ratio",
    "lockstep.cpu_us_per_step.composed_no_intra_process",
    "lockstep.up_ros2_steps_per_s",
    "lockstep.composed_ros2_steps_per_s",
    "lockstep.cpu_us_per_step.up_ros2",
    "lockstep.cpu_us_per_step.composed_ros2",
    *(
        f"lockstep.sensors.{where}.{field}"
        for where in ("inprocess", "separate", "composed")
        for field in ("steps_per_s", "without_steps_per_s")
    ),
    "lockstep.cpu_us_per_step.up",
    "lockstep.cpu_us_per_step.up_not_recording",
    "lockstep.cpu_us_per_step.composed",
    "lockstep.cpu_us_per_step.composed_recording",
    "lockstep.latency_us.p50",
    "lockstep.latency_us.p99",
    "realtime.rate_hz",
    "realtime.late_fraction",
    "realtime.latency_us.p50",
    "realtime.latency_us.p99",
    "realtime.floor_latency_us.p99",
    "realtime.floor_late_fraction",
    *(
        f"realtime.{variant}.{field}"
        for variant in ("rt", "rt_any_cpu", "rt_gc_automatic", "rt_gc_idle")
        for field in ("late_fraction", "latency_us.p99", "p99_vs_floor", "cpu_us_per_step")
    ),
    "fleet.workers_speedup.2",
    "fleet.world_us_per_step.2",
    "fleet.spread_bound.2",
    "machine.cores",
    *(
        f"engines.{engine}.{field}"
        for engine in ("pybullet", "kinematic")
        for field in ("separate_real_time_factor", "composed_real_time_factor", "us_per_step")
    ),
    *(f"engines.ratio.{layout}" for layout in ("separate", "composed", "inprocess")),
    *(
        f"fleet.{mode}.2.{field}"
        for mode in ("separate", "composed", "composed_workers")
        for field in ("steps_per_s", "robot_steps_per_s", "cpu_us_per_robot_step", "late_fraction")
    ),
    "fleet.separate.2.sim_share",
    *(f"navigation.costmap.{layer}.{field}" for layer in ("no_map", "map") for field in ("ms", "share")),
    *(f"localization.amcl.{count}.{field}" for count in ("converged", "max_particles") for field in ("ms", "share")),
    "localization.amcl.field_build_ms",
    *(
        f"localization.mapping.{field}"
        for field in ("ms_per_scan_median", "period_share", "wall_s_per_simulated_minute")
    ),
    *(
        f"navigation.plan.{scenario}.{field}"
        for scenario in ("building", "seen", "open")
        for field in ("plan_ms", "share")
    ),
    *(
        f"ros2_fleet.1.{field}"
        for field in (
            "steps_per_s",
            "cpu_us_per_robot_step",
            "bridge_cpu_ms_per_robot_per_sim_s",
            "bridge_rss_mb_per_robot",
        )
    ),
)
MESSAGE_TYPES = ("Time", "TimedDoubleSeq", "TimedVelocity", "TimedPosition", "BumpEvent", "PDGains", "NoArguments")


def _lookup(results: dict, dotted: str):
    value = results
    for part in dotted.split("."):
        value = value[part]
    return value


ROS2_FLEET_AND_MACHINE = tuple(name for name in NUMBERS if name.startswith(("ros2_fleet.", "machine.")))


def _quick_bench(out: Path, *only: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    result = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--quick", "--out", str(out), *(("--only", *only) if only else ())],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=270,  # every section quick, ros2_fleet's fleet run among them, on a loaded 2-core machine
        check=False,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    results = json.loads(out.read_text())
    assert results["failures"] == []
    return result, results


def _numbers_written(results: dict, names: tuple[str, ...]) -> None:
    for name in names:
        value = _lookup(results, name)
        lowest = 0 if name.endswith("late_fraction") else 1e-9
        assert isinstance(value, (int, float)) and value >= lowest, (name, value)


def _codec_written(results: dict) -> None:
    for name in MESSAGE_TYPES:
        entry = results["codec"][name]
        assert entry["codec_ns"] > 0 and entry["json_ns"] > 0 and entry["ratio"] == entry["json_ns"] / entry["codec_ns"]


def _fleet_written(result: subprocess.CompletedProcess[str], results: dict) -> None:
    assert results["fleet"]["sizes"] == [2]
    assert results["fleet"]["composed"]["2"]["sim_share"] is None  # one thread: not separable
    assert "| robots | mode | steps/s |" in result.stdout
    assert "| robots | steps/s without → with |" in result.stdout


def test_the_quick_ros2_fleet_and_codec_sections_write_their_fields(tmp_path):
    """The part of the quick bench ``make test`` runs (about 8 s); the loop's and the fleet's
    sections, about 80 s, are ``make bench-smoke``'s (below)."""
    result, results = _quick_bench(tmp_path / "latest.json", "ros2_fleet", "codec")
    _numbers_written(results, ROS2_FLEET_AND_MACHINE)
    _codec_written(results)
    assert "| robots | steps/s without → with |" in result.stdout


@pytest.mark.bench_smoke
def test_quick_bench_writes_every_field_and_prints_the_table(tmp_path):
    out = tmp_path / "latest.json"
    result, results = _quick_bench(out)
    _numbers_written(results, NUMBERS)
    for where in ("inprocess", "separate", "composed"):
        # a difference of two timed runs: a quick run on a busy machine may make it negative
        sensors = results["lockstep"]["sensors"][where]
        assert sensors["cost"] == 1.0 - sensors["steps_per_s"] / sensors["without_steps_per_s"], where
    _codec_written(results)
    assert {"python", "zenoh", "pybullet", "date"} <= set(results["machine"])
    assert set(results["targets"]) == {
        "lockstep.floor_ratio",
        "lockstep.composed_ratio",
        "realtime.late_fraction",
        "realtime.latency_us.p99",
        "codec.min_ratio",
        "fleet.composed.4.steps_per_s",
        "realtime.rt.late_vs_floor",
        "realtime.rt.p99_vs_floor",
        "fleet.workers_speedup.8",
    }
    assert results["realtime"]["rt"]["sched"] == ("SCHED_FIFO 50" if os.geteuid() == 0 else "SCHED_OTHER 0")
    _fleet_written(result, results)
    assert "| lockstep, separate processes |" in result.stdout and f"wrote {out}" in result.stdout
    assert "| lockstep square | PyBullet | kinematic | kinematic / PyBullet |" in result.stdout


def test_the_quick_navigation_section_writes_its_fields_and_its_table():
    """In-process (no subprocess, a few seconds): the costmap's updates and the plans, timed but not judged."""
    failures: list[str] = []
    results = navigation.run_section(argparse.Namespace(quick=True), failures)
    assert failures == []
    _numbers_written({"navigation": results}, tuple(name for name in NUMBERS if name.startswith("navigation.")))
    for entry in results["plan"].values():
        assert entry["points"] >= 2
        assert entry["length_m"] >= math.dist(navigation.START, navigation.GOAL) - 1e-9, "no shorter than the line"
    assert "| costmap update per scan, no map |" in navigation.table(results)


def test_the_quick_localization_section_writes_its_fields_and_its_table():
    """In-process: the particle filter's updates and a map from a synthetic run, timed but not judged."""
    failures: list[str] = []
    results = localization.run_section(argparse.Namespace(quick=True), failures)
    assert failures == []
    _numbers_written({"localization": results}, tuple(name for name in NUMBERS if name.startswith("localization.")))
    table = localization.table(results)
    assert "| amcl update per scan, converged |" in table and "| map from a run, per scan |" in table


def test_the_spread_bound_is_amdahls_law_of_the_worlds_own_work():
    assert fleet.spread_bound(300.0, 100.0, 2) == pytest.approx(300.0 / 200.0)
    assert fleet.spread_bound(300.0, 0.0, 2) == pytest.approx(2.0), "nothing serial: every core counts"
    assert fleet.spread_bound(300.0, 300.0, 8) == pytest.approx(1.0), "all serial: no core helps"
    assert fleet.spread_bound(80.0, 100.0, 2) == pytest.approx(0.8), "timed above the wall step: never above 1"


def test_the_default_results_file_is_not_tracked_so_a_bench_leaves_a_clone_clean():
    relative = RESULTS.relative_to(REPO)
    assert subprocess.run(["git", "check-ignore", "-q", str(relative)], cwd=REPO, check=False).returncode == 0
    tracked = subprocess.run(
        ["git", "ls-files", "--error-unmatch", str(relative)], cwd=REPO, capture_output=True, check=False
    )
    assert tracked.returncode != 0, f"{relative} is tracked"


@pytest.mark.parametrize(
    ("late", "share"),
    [((0, 0, 9, 0, 1), 0.9), ((2, 2, 2, 2, 2), 0.2)],
    ids=["a burst", "evenly"],
)
def test_the_lateness_summary_tells_a_burst_from_late_steps_spread_evenly(late, share):
    intervals = [{"late": count, "steps": 200, "steal_ms": 5.0 if count else 1.0} for count in late]
    result = lateness.summary(intervals)
    assert result["late_steps"] == sum(late)
    assert result["late_fraction"] == sum(late) / 1000
    assert result["intervals_with_late_steps"] == sum(1 for count in late if count)
    assert result["late_share_in_worst_5_percent_of_intervals"] == pytest.approx(share)
    assert result["most_late_in_one_interval"] == max(late)
    assert result["steal_ms_per_interval_with_late_steps"] == 5.0
    assert result["steal_ms_per_interval_without"] == (1.0 if 0 in late else None)
