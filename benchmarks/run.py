"""``make bench``: measure, print a table, write ``benchmarks/results/latest.json``.

Sections (benchmarks/README.md explains each number and what was tried to push them):

- ``lockstep``: steps per second of the real loop (router, motor, odometry, localization, sim
  and drive, each its own process, started as ``invent up`` starts them), of ``invent up``
  itself recording its run.mcap and with ``--no-record``, of the composed loop (``invent up
  --composed --no-record``, and recording, as plain ``invent up --composed``) and of the
  in-process limit, with their ratios and what recording costs in each mode; what the ROS 2 bridge
  beside the loop (``--ros2``) costs, separate and composed; the step exchange latency measured by
  the sim.
- ``lockstep.floor_*``: the floor zenoh sets: a bare zenoh-python ping-pong between two processes
  configured as the services are (``benchmarks/floor.py``), and the separate-process loop's steps
  per second against it (``floor_ratio``): one lockstep step needs at least one such round trip.
- ``realtime``: the same processes with the sim in realtime mode at 1 kHz: achieved rate,
  late fraction, torque latency; and the floor ping-pong paced at 1 kHz (``floor_*``): its round
  trips' latency and the fraction longer than a period, what the bare exchange would count late.
- ``codec``: ns per encode + decode per message type, the project's codec against stdlib json.
- ``fleet``: how the loop scales with the robots of one world (``invent up --fleet --no-record``,
  N = 1, 2, 4, 8, separate and composed): steps/s, CPU per robot-step, the sim's share of the CPU
  (``benchmarks/fleet.py``).
- ``ros2_fleet``: what the ROS 2 bridge of each robot of a fleet costs (``invent up --fleet --no-record``
  with and without ``--ros2``, N = 1, 2, 4): the bridges' CPU per robot per simulated second and memory
  per robot, the loop's steps/s and CPU per robot-step with and without (``benchmarks/ros2_fleet.py``).
- ``machine``: where it ran.

Loop figures are medians over ``--repeats`` runs (lockstep runs interleaved with the in-process
limit, so a ratio compares numbers taken under the same machine load).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks import codec, floor, loop, machine, ros2_fleet
from benchmarks import fleet as fleet_bench
from services.runtime.session import LOW_LATENCY_VARIABLE

RESULTS = Path(__file__).resolve().parent / "results" / "latest.json"

TARGETS = {
    "lockstep.floor_ratio": 0.5,
    "lockstep.composed_ratio": 0.4,
    "realtime.late_fraction": 0.001,
    "realtime.latency_us.p99": 500.0,
    "codec.min_ratio": 5.0,
    "fleet.composed.4.steps_per_s": 1000.0,
    "realtime.rt.late_vs_floor": 1.5,
    "realtime.rt.p99_vs_floor": 1.5,
    "fleet.workers_speedup.8": 1.5,
}
"""The issues' "Must show": ratios are lower bounds, late fraction and latency upper bounds; the fleet's
(issue 26): composed with 4 robots at least at real time (1,000 steps/s at the default 1 ms step)."""
UPPER_BOUNDS = frozenset(
    {"realtime.late_fraction", "realtime.latency_us.p99", "realtime.rt.late_vs_floor", "realtime.rt.p99_vs_floor"}
)
"""Issue 32's: realtime 1 kHz with ``--rt`` within 1.5x the paced floor's late fraction and p99; a composed
fleet of 8 over one process per core (``--workers``) at 1.5x its robot-steps/s in one process."""


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--repeats", type=int, default=3, help="runs per loop mode, lockstep and realtime (median reported; default 3)"
    )
    parser.add_argument("--warmup", type=float, default=1.0, metavar="S", help="wall seconds before measuring")
    parser.add_argument("--window", type=float, default=4.0, metavar="S", help="lockstep measuring window, wall s")
    parser.add_argument(
        "--realtime-window", type=float, default=10.0, metavar="S", help="realtime measuring window, wall s"
    )
    parser.add_argument("--inprocess", type=float, default=2.0, metavar="S", help="in-process limit run, wall s")
    parser.add_argument("--floor", type=float, default=3.0, metavar="S", help="zenoh ping-pong floor run, wall s")
    parser.add_argument("--codec-repeats", type=int, default=5, metavar="N", help="timed batches per codec figure")
    parser.add_argument("--out", type=Path, default=RESULTS, help=f"results file (default {RESULTS})")
    parser.add_argument("--quick", action="store_true", help="tiny durations: checks that everything runs")
    parser.add_argument(
        "--fleet-sizes",
        type=_sizes,
        default=FLEET_SIZES,
        metavar="N,N,...",
        help=f"robots per fleet run (default {','.join(map(str, FLEET_SIZES))}; --quick: 2)",
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=SECTIONS,
        metavar="SECTION",
        help=f"run only these sections ({', '.join(SECTIONS)}: loop is lockstep and realtime; default all); the "
        "others' targets are then not measured",
    )
    return parser


SECTIONS = ("loop", "codec", "fleet", "ros2_fleet")
"""``loop``: the ``lockstep`` and ``realtime`` sections; ``fleet``: benchmarks/fleet.py; ``ros2_fleet``:
the ROS 2 bridge of each robot of a fleet, benchmarks/ros2_fleet.py."""
FLEET_SIZES = (1, 2, 4, 8)
QUICK_FLEET_SIZES = (2,)


def _sizes(text: str) -> tuple[int, ...]:
    sizes = tuple(int(value) for value in text.split(","))
    if not sizes or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"robot counts must be positive integers: {text!r}")
    return sizes


def composed_available() -> bool:
    """Whether this checkout's ``invent up`` has ``--composed`` and ``--no-record``."""
    help_text = subprocess.run(
        [sys.executable, "-m", "services.cli", "up", "--help"],
        cwd=loop.REPO,
        capture_output=True,
        text=True,
        check=False,
    ).stdout
    return loop.COMPOSED_FLAG in help_text and loop.NO_RECORD_FLAG in help_text


def _median(values: Sequence[float | None]) -> float | None:
    present = [value for value in values if value is not None]
    return statistics.median(present) if present else None


def _ratio(numerator: float | None, denominator: float | None) -> float | None:
    return numerator / denominator if numerator is not None and denominator else None


def _cost(recording: float | None, not_recording: float | None) -> float | None:
    """How much slower the loop ran with its recorder, in % of the speed without (measured in the same run)."""
    ratio = _ratio(recording, not_recording)
    return None if ratio is None else 100.0 * (1.0 - ratio)


def _cpu_cost(recording: float | None, not_recording: float | None) -> float | None:
    """How much more CPU per step the loop took with its recording, in % of the CPU without."""
    ratio = _ratio(recording, not_recording)
    return None if ratio is None else 100.0 * (ratio - 1.0)


def _cpu_per_step(runs: list[loop.LoopResult]) -> float | None:
    return _median([run.cpu_us_per_step for run in runs])


def _keep(runs: list[loop.LoopResult], result: loop.LoopResult | None) -> None:
    """Add ``result`` to ``runs`` unless the run failed (None: listed under ``failures``)."""
    if result is not None:
        runs.append(result)


def _timed(what: str, action: Callable[[], Any], failures: list[str]) -> Any:
    """``action()``, timed on the console; None (and the reason in ``failures``) if a run failed."""
    started = time.monotonic()
    print(f"  {what} ...", end="", flush=True)
    try:
        result = action()
    except RuntimeError as error:
        print(f" failed: {str(error).splitlines()[0]}", flush=True)
        failures.append(f"{what}: {error}")
        return None
    print(f" {time.monotonic() - started:.1f} s", flush=True)
    return result


def _loop_summary(runs: list[loop.LoopResult]) -> dict[str, Any]:
    return {
        "steps_per_s": _median([run.steps_per_s for run in runs]),
        "latency_us": {
            "p50": _median([run.latency_us["p50"] for run in runs]),
            "p99": _median([run.latency_us["p99"] for run in runs]),
        },
        "late_fraction": _median([run.late_fraction for run in runs]),
    }


def run_lockstep(args: argparse.Namespace, composed: bool, failures: list[str]) -> dict[str, Any]:
    inprocess: list[float] = []
    floors: list[dict[str, float]] = []
    separate: list[loop.LoopResult] = []
    separate_rt: list[loop.LoopResult] = []
    with_up: list[loop.LoopResult] = []
    up_not_recording: list[loop.LoopResult] = []
    low_latency: list[loop.LoopResult] = []
    together: list[loop.LoopResult] = []
    together_rt: list[loop.LoopResult] = []
    together_no_intra: list[loop.LoopResult] = []
    together_recording: list[loop.LoopResult] = []
    up_ros2: list[loop.LoopResult] = []
    together_ros2: list[loop.LoopResult] = []
    for repeat in range(args.repeats):
        print(f"lockstep, run {repeat + 1} of {args.repeats}", flush=True)
        inprocess.append(_timed("in-process limit", lambda: loop.inprocess_steps_per_s(args.inprocess), failures))
        floors.append(
            _timed(
                "zenoh ping-pong floor",
                lambda: floor.measure(args.floor, f"tcp/127.0.0.1:{loop.free_port()}"),
                failures,
            )
        )
        _keep(
            separate,
            _timed("separate processes", lambda: loop.measure_services([], args.warmup, args.window), failures),
        )
        _keep(
            separate_rt,
            _timed(
                "separate, --rt on the control path",
                lambda: loop.measure_services([], args.warmup, args.window, None, [loop.RT_FLAG]),
                failures,
            ),
        )
        _keep(
            low_latency,
            _timed(
                "separate, low-latency transport",
                lambda: loop.measure_services([], args.warmup, args.window, {LOW_LATENCY_VARIABLE: "1"}),
                failures,
            ),
        )
        _keep(with_up, _timed("invent up (recording)", lambda: loop.measure_up([], args.warmup, args.window), failures))
        _keep(
            up_not_recording,
            _timed(
                "invent up --no-record",
                lambda: loop.measure_up([loop.NO_RECORD_FLAG], args.warmup, args.window),
                failures,
            ),
        )
        _keep(
            up_ros2,
            _timed(
                "invent up --no-record --ros2",
                lambda: loop.measure_up([loop.NO_RECORD_FLAG, loop.ROS2_FLAG], args.warmup, args.window),
                failures,
            ),
        )
        if composed:
            _keep(
                together_ros2,
                _timed(
                    "composed, --ros2",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.ROS2_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            _keep(
                together,
                _timed(
                    "composed",
                    lambda: loop.measure_up([loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG], args.warmup, args.window),
                    failures,
                ),
            )
            _keep(
                together_rt,
                _timed(
                    "composed, --rt",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.RT_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            _keep(
                together_no_intra,
                _timed(
                    "composed, no intra-process delivery",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.NO_INTRA_PROCESS_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            _keep(
                together_recording,
                _timed(
                    "composed, recording",
                    lambda: loop.measure_up([loop.COMPOSED_FLAG], args.warmup, args.window),
                    failures,
                ),
            )
    inprocess = [value for value in inprocess if value is not None]
    floors = [value for value in floors if value is not None]
    floor_rate = _median([value["round_trips_per_s"] for value in floors])

    limit = _median(inprocess)
    alone, shared = _loop_summary(separate), _loop_summary(together) if together else None
    return {
        "steps_per_s": alone["steps_per_s"],
        "inprocess_steps_per_s": limit,
        "ratio": _ratio(alone["steps_per_s"], limit),
        "floor_round_trips_per_s": floor_rate,
        "floor_ratio": _ratio(alone["steps_per_s"], floor_rate),
        "floor_latency_us": {
            quantile: _median([value[f"{quantile}_us"] for value in floors]) for quantile in ("p50", "p99")
        },
        "latency_us": alone["latency_us"],
        "late_fraction": alone["late_fraction"],
        "rt_steps_per_s": _median([run.steps_per_s for run in separate_rt]),
        "rt_floor_ratio": _ratio(_median([run.steps_per_s for run in separate_rt]), floor_rate),
        "rt_latency_us": _loop_summary(separate_rt)["latency_us"] if separate_rt else None,
        "up_steps_per_s": _median([run.steps_per_s for run in with_up]),
        "up_not_recording_steps_per_s": _median([run.steps_per_s for run in up_not_recording]),
        "lowlatency_steps_per_s": _median([run.steps_per_s for run in low_latency]),
        "lowlatency_ratio": _ratio(_median([run.steps_per_s for run in low_latency]), limit),
        "lowlatency_latency_us": _loop_summary(low_latency)["latency_us"],
        "composed_steps_per_s": shared["steps_per_s"] if shared else None,
        "composed_ratio": _ratio(shared["steps_per_s"], limit) if shared else None,
        "composed_latency_us": shared["latency_us"] if shared else None,
        "composed_rt_steps_per_s": _median([run.steps_per_s for run in together_rt]),
        "composed_rt_ratio": _ratio(_median([run.steps_per_s for run in together_rt]), limit),
        "composed_no_intra_process_steps_per_s": _median([run.steps_per_s for run in together_no_intra]),
        "composed_no_intra_process_ratio": _ratio(_median([run.steps_per_s for run in together_no_intra]), limit),
        "composed_recording_steps_per_s": _median([run.steps_per_s for run in together_recording]),
        "up_ros2_steps_per_s": _median([run.steps_per_s for run in up_ros2]),
        "composed_ros2_steps_per_s": _median([run.steps_per_s for run in together_ros2]),
        "cpu_us_per_step": {
            "separate": _cpu_per_step(separate),
            "rt": _cpu_per_step(separate_rt),
            "up": _cpu_per_step(with_up),
            "up_not_recording": _cpu_per_step(up_not_recording),
            "composed": _cpu_per_step(together),
            "composed_rt": _cpu_per_step(together_rt),
            "composed_no_intra_process": _cpu_per_step(together_no_intra),
            "composed_recording": _cpu_per_step(together_recording),
            "up_ros2": _cpu_per_step(up_ros2),
            "composed_ros2": _cpu_per_step(together_ros2),
        },
        "composed_note": (
            None if composed else f"this checkout's `invent up` has no {loop.COMPOSED_FLAG} {loop.NO_RECORD_FLAG}"
        ),
        "runs": {
            "inprocess_steps_per_s": inprocess,
            "floor": floors,
            "separate": [run.as_dict() for run in separate],
            "rt": [run.as_dict() for run in separate_rt],
            "up": [run.as_dict() for run in with_up],
            "up_not_recording": [run.as_dict() for run in up_not_recording],
            "lowlatency": [run.as_dict() for run in low_latency],
            "composed": [run.as_dict() for run in together],
            "composed_rt": [run.as_dict() for run in together_rt],
            "composed_no_intra_process": [run.as_dict() for run in together_no_intra],
            "composed_recording": [run.as_dict() for run in together_recording],
            "up_ros2": [run.as_dict() for run in up_ros2],
            "composed_ros2": [run.as_dict() for run in together_ros2],
        },
    }


REALTIME_HZ = 1000.0
"""The realtime runs' step rate (the sim's default: 1 ms steps at a realtime factor of 1)."""


RT_VARIANTS = {
    "rt": [loop.RT_FLAG],
    "rt_any_cpu": [loop.RT_FLAG, "--set", 'rt.cpus="any"'],
    "rt_gc_automatic": [loop.RT_FLAG, "--set", 'rt.gc="automatic"'],
    "rt_gc_idle": [loop.RT_FLAG, "--set", 'rt.gc="idle"'],
}
"""The realtime runs with ``--rt`` on the control path (router, motor, sim), as ``invent up --rt``
gives it: its defaults (the control path on the last CPU, the collector frozen), the CPUs left to the
system, and the two other collector policies, to measure what each does."""


def _realtime_summary(runs: list[loop.LoopResult], floor_late: float | None, floor_p99: float | None) -> dict[str, Any]:
    late = _median([run.late_fraction for run in runs])
    p99 = _median([run.latency_us["p99"] for run in runs])
    gc_runs = [run.gc for run in runs if run.gc]
    return {
        "late_fraction": late,
        "missing_fraction": _median([run.missing_fraction for run in runs]),
        "latency_us": {
            quantile: _median([run.latency_us[quantile] for run in runs]) for quantile in ("p50", "p99", "max")
        },
        "late_vs_floor": _ratio(late, floor_late),
        "p99_vs_floor": _ratio(p99, floor_p99),
        "cpu_us_per_step": _cpu_per_step(runs),
        "gc_pause_us_per_step": _median([entry["pause_us_per_step"] for entry in gc_runs]),
        "gc_max_pause_us": _median([entry["max_pause_us_since_start"] for entry in gc_runs]),
        "gc_collections_per_run": _median([sum(entry["collections"]) for entry in gc_runs]),
        "sched": gc_runs[-1]["sched"] if gc_runs else None,
        "cpus": gc_runs[-1].get("cpus") if gc_runs else None,
        "runs": [run.as_dict() for run in runs],
    }


def run_realtime(args: argparse.Namespace, failures: list[str]) -> dict[str, Any]:
    runs: list[loop.LoopResult] = []
    floors: list[dict[str, float]] = []
    variants: dict[str, list[loop.LoopResult]] = {name: [] for name in RT_VARIANTS}
    for repeat in range(args.repeats):
        print(f"realtime, 1 kHz, run {repeat + 1} of {args.repeats}", flush=True)
        floors.append(
            _timed(
                "zenoh ping-pong paced at 1 kHz (floor)",
                lambda: floor.measure(args.realtime_window, f"tcp/127.0.0.1:{loop.free_port()}", REALTIME_HZ),
                failures,
            )
        )
        _keep(
            runs,
            _timed(
                "separate processes",
                lambda: loop.measure_services(["--mode", "realtime"], args.warmup, args.realtime_window),
                failures,
            ),
        )
        for name, flags in RT_VARIANTS.items():
            _keep(
                variants[name],
                _timed(
                    f"separate processes, {' '.join(flags)}",
                    functools.partial(
                        loop.measure_services, ["--mode", "realtime"], args.warmup, args.realtime_window, None, flags
                    ),
                    failures,
                ),
            )
    floors = [value for value in floors if value is not None]
    floor_late = _median([value["longer_than_period_fraction"] for value in floors])
    floor_p99 = _median([value["p99_us"] for value in floors])
    return {
        **{name: _realtime_summary(results, floor_late, floor_p99) for name, results in variants.items()},
        "late_vs_floor": _ratio(_median([run.late_fraction for run in runs]), floor_late),
        "p99_vs_floor": _ratio(_median([run.latency_us["p99"] for run in runs]), floor_p99),
        "rate_hz": _median([run.steps_per_s for run in runs]),
        "floor_latency_us": {
            quantile: _median([value[f"{quantile}_us"] for value in floors]) for quantile in ("p50", "p99", "max")
        },
        "floor_late_fraction": _median([value["longer_than_period_fraction"] for value in floors]),
        "real_time_factor": _median([run.sim_seconds_per_s for run in runs]),
        "late_fraction": _median([run.late_fraction for run in runs]),
        "missing_fraction": _median([run.missing_fraction for run in runs]),
        "latency_us": {
            quantile: _median([run.latency_us[quantile] for run in runs]) for quantile in ("p50", "p99", "max")
        },
        "runs": [run.as_dict() for run in runs],
        "floor_runs": floors,
    }


FLEET_MODES = tuple(fleet_bench.MODES)
FLEET_FIELDS = (
    "steps_per_s",
    "robot_steps_per_s",
    "cpu_us_per_robot_step",
    "sim_share",
    "late_fraction",
    "cpu_cores",
)


def run_fleet(args: argparse.Namespace, composed: bool, failures: list[str]) -> dict[str, Any]:
    """``invent up --fleet --no-record`` of each size, separate and composed, runs interleaved; per
    mode and size (as a string: a JSON key) the medians of :data:`FLEET_FIELDS`."""
    modes = [mode for mode in FLEET_MODES if composed or mode == "separate"]
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {
        mode: {str(size): [] for size in args.fleet_sizes} for mode in modes
    }
    world: dict[str, list[float]] = {str(size): [] for size in args.fleet_sizes}
    for repeat in range(args.repeats):
        print(f"fleet, run {repeat + 1} of {args.repeats}", flush=True)
        for size in args.fleet_sizes:
            world_us = _timed(
                f"{size} robot{'s' * (size > 1)}, the world's own work in place",
                functools.partial(fleet_bench.world_step_us, size, args.inprocess),
                failures,
            )
            if world_us is not None:
                world[str(size)].append(world_us)
            for mode in modes:
                result = _timed(
                    f"{size} robot{'s' * (size > 1)}, {mode}",
                    functools.partial(fleet_bench.measure_fleet, size, mode, args.warmup, args.window),
                    failures,
                )
                if result is not None:
                    runs[mode][str(size)].append(result.as_dict())
    medians = {
        mode: {
            size: {field: _median([run[field] for run in sized]) for field in FLEET_FIELDS}
            for size, sized in by_size.items()
        }
        for mode, by_size in runs.items()
    }
    one, spread = medians.get("composed", {}), medians.get("composed_workers", {})
    world_us = {size: _median(values) for size, values in world.items()}
    cores = os.cpu_count() or 1
    return {
        "sizes": list(args.fleet_sizes),
        **medians,
        "workers_speedup": {
            size: _ratio(spread.get(size, {}).get("robot_steps_per_s"), one.get(size, {}).get("robot_steps_per_s"))
            for size in one
        },
        "world_us_per_step": world_us,
        "spread_bound": {
            size: fleet_bench.spread_bound(1e6 / entry["steps_per_s"], world_us[size], cores)
            for size, entry in one.items()
            if entry.get("steps_per_s") and world_us.get(size) is not None
        },
        "spread_bound_note": (
            f"the most --workers {cores} could gain over one process if everything but the world's own work "
            "(world_us_per_step: PyBullet, which holds the GIL, for every robot) were shared perfectly over "
            f"{cores} cores and cost nothing to hand over (Amdahl's law, from the composed run's world step)"
        ),
        "load_average_at_end": [round(load, 2) for load in os.getloadavg()],
        "sim_share_note": fleet_bench.COMPOSED_SIM_SHARE_NOTE,
        "composed_note": None if composed else f"this checkout's `invent up` has no {loop.COMPOSED_FLAG}",
        "runs": runs,
    }


def _lookup(results: dict[str, Any], dotted: str) -> Any:
    value: Any = results
    for part in dotted.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return value


def check_targets(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    checks = {}
    for name, target in TARGETS.items():
        value = _lookup(results, name)
        met = None if value is None else (value < target if name in UPPER_BOUNDS else value >= target)
        checks[name] = {"target": target, "value": value, "met": met}
    return checks


def _percent(fraction: float | None) -> float | None:
    return None if fraction is None else 100 * fraction


def _fmt(value: Any, digits: int = 0) -> str:
    if value is None:
        return "n/a"
    return f"{value:,.{digits}f}"


def _cost_line(what: str, lockstep: dict[str, Any], cpu: dict[str, Any], loaded: str, bare: str) -> str:
    """What ``what`` (recording, the ROS 2 bridge) cost the loop of one mode, in steps/s and in CPU
    per step: the run ``loaded`` against the run ``bare``, measured in the same session."""
    steps = _cost(lockstep[f"{loaded}_steps_per_s"], lockstep[f"{bare}_steps_per_s"])
    cpu_cost = _cpu_cost(cpu.get(loaded), cpu.get(bare))
    return (
        f"{what} costs {_fmt(steps, 1)} % of the steps/s, {_fmt(cpu_cost, 1)} % CPU per step "
        f"({_fmt(cpu.get(loaded))} vs {_fmt(cpu.get(bare))} µs)"
    )


def _loop_rows(results: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The ``lockstep`` and ``realtime`` sections' rows of :func:`table`."""
    lockstep, realtime = results["lockstep"], results["realtime"]
    cpu = lockstep.get("cpu_us_per_step") or {}
    rows = [
        (
            "lockstep, separate processes",
            f"{_fmt(lockstep['steps_per_s'])} steps/s",
            f"ratio {_fmt(lockstep['ratio'], 3)}",
        ),
        (
            "lockstep, separate, `--rt` on the control path (router, motor, sim)",
            f"{_fmt(lockstep.get('rt_steps_per_s'))} steps/s",
            (
                f"floor ratio {_fmt(lockstep.get('rt_floor_ratio'), 3)}; CPU {_fmt(cpu.get('rt'))} vs "
                f"{_fmt(cpu.get('separate'))} µs per step without"
            ),
        ),
        (
            "floor: bare zenoh ping-pong between two processes",
            f"{_fmt(lockstep['floor_round_trips_per_s'])} round trips/s",
            f"p50 {_fmt(lockstep['floor_latency_us']['p50'])} µs; separate loop / floor = {_fmt(lockstep['floor_ratio'], 3)}",
        ),
        (
            f"lockstep, separate, low-latency transport (opt-in, `{LOW_LATENCY_VARIABLE}=1`)",
            f"{_fmt(lockstep['lowlatency_steps_per_s'])} steps/s",
            f"ratio {_fmt(lockstep['lowlatency_ratio'], 3)}",
        ),
        (
            "lockstep, `invent up --no-record`",
            f"{_fmt(lockstep['up_not_recording_steps_per_s'])} steps/s",
            f"ratio {_fmt(_ratio(lockstep['up_not_recording_steps_per_s'], lockstep['inprocess_steps_per_s']), 3)}",
        ),
        (
            "lockstep, `invent up` (recording run.mcap)",
            f"{_fmt(lockstep['up_steps_per_s'])} steps/s",
            _cost_line("recording", lockstep, cpu, "up", "up_not_recording"),
        ),
        (
            "lockstep, composed (`invent up --composed --no-record`)",
            f"{_fmt(lockstep['composed_steps_per_s'])} steps/s",
            f"ratio {_fmt(lockstep['composed_ratio'], 3)}",
        ),
        (
            "lockstep, composed, `--rt`",
            f"{_fmt(lockstep.get('composed_rt_steps_per_s'))} steps/s",
            f"ratio {_fmt(lockstep.get('composed_rt_ratio'), 3)}",
        ),
        (
            "lockstep, composed, no intra-process delivery (`--no-intra-process`)",
            f"{_fmt(lockstep.get('composed_no_intra_process_steps_per_s'))} steps/s",
            (
                f"ratio {_fmt(lockstep.get('composed_no_intra_process_ratio'), 3)}; CPU "
                f"{_fmt(cpu.get('composed_no_intra_process'))} vs {_fmt(cpu.get('composed'))} µs per step with it"
            ),
        ),
        (
            "lockstep, composed, recording run.mcap (`invent up --composed`)",
            f"{_fmt(lockstep['composed_recording_steps_per_s'])} steps/s",
            _cost_line("recording", lockstep, cpu, "composed_recording", "composed"),
        ),
        (
            "lockstep, `invent up --no-record --ros2`",
            f"{_fmt(lockstep['up_ros2_steps_per_s'])} steps/s",
            _cost_line("the ROS 2 bridge", lockstep, cpu, "up_ros2", "up_not_recording"),
        ),
        (
            "lockstep, composed, `--ros2`",
            f"{_fmt(lockstep['composed_ros2_steps_per_s'])} steps/s",
            _cost_line("the ROS 2 bridge", lockstep, cpu, "composed_ros2", "composed"),
        ),
        ("lockstep, in one process, no zenoh (limit)", f"{_fmt(lockstep['inprocess_steps_per_s'])} steps/s", "1"),
        (
            "lockstep torque latency, separate",
            f"p50 {_fmt(lockstep['latency_us']['p50'])} µs",
            f"p99 {_fmt(lockstep['latency_us']['p99'])} µs",
        ),
        (
            "realtime 1 kHz, separate processes",
            f"{_fmt(realtime['rate_hz'])} steps/s",
            (
                f"late {_fmt(_percent(realtime['late_fraction']), 2)} % ({_fmt(realtime.get('late_vs_floor'), 2)}x the "
                f"floor's), p99 {_fmt(realtime.get('p99_vs_floor'), 2)}x the floor's"
            ),
        ),
        (
            "realtime torque latency",
            f"p50 {_fmt(realtime['latency_us']['p50'])} µs",
            f"p99 {_fmt(realtime['latency_us']['p99'])} µs",
        ),
        (
            "realtime floor: bare zenoh ping-pong paced at 1 kHz",
            f"p50 {_fmt(realtime['floor_latency_us']['p50'])} µs, p99 {_fmt(realtime['floor_latency_us']['p99'])} µs",
            f"longer than 1 ms: {_fmt(_percent(realtime['floor_late_fraction']), 2)} %",
        ),
    ]
    for name, flags in RT_VARIANTS.items():
        variant = realtime.get(name)
        if variant is None:
            continue
        rows.append(
            (
                (
                    f"realtime 1 kHz, separate, `{' '.join(flags)}` on the control path ({variant['sched']}, "
                    f"CPUs {variant.get('cpus') or 'any'})"
                ),
                f"late {_fmt(_percent(variant['late_fraction']), 2)} %, p99 {_fmt(variant['latency_us']['p99'])} µs",
                (
                    f"{_fmt(variant['late_vs_floor'], 2)}x / {_fmt(variant['p99_vs_floor'], 2)}x the floor's; collector "
                    f"{_fmt(variant['gc_collections_per_run'])} collections and {_fmt(variant['gc_pause_us_per_step'], 2)} µs "
                    f"per step in the window, longest pause since start-up {_fmt(variant['gc_max_pause_us'])} µs"
                ),
            )
        )
    return rows


def fleet_table(fleet: dict[str, Any]) -> str:
    """The ``fleet`` section as a Markdown table: per size and mode, the medians of its runs."""
    lines = [
        "| robots | mode | steps/s | robot-steps/s | CPU µs per robot-step | sim's share of the CPU | cores busy |",
        "|---|---|---|---|---|---|---|",
    ]
    for size in fleet["sizes"]:
        for mode in FLEET_MODES:
            entry = fleet.get(mode, {}).get(str(size))
            if entry is None:
                continue
            share = "n/a (composed)" if mode != "separate" else f"{_fmt(_percent(entry['sim_share']))} %"
            lines.append(
                f"| {size} | {mode} | {_fmt(entry['steps_per_s'])} | {_fmt(entry['robot_steps_per_s'])} | "
                f"{_fmt(entry['cpu_us_per_robot_step'])} | {share} | {_fmt(entry['cpu_cores'], 2)} |"
            )
    speedups = fleet.get("workers_speedup") or {}
    if speedups:
        lines += [
            "",
            "Composed over one process per core (`--workers` the cores) against one process (`--workers 1`, the default), robot-steps/s: "
            + ", ".join(f"N = {size}: {_fmt(ratio, 2)}x" for size, ratio in speedups.items()),
        ]
    bounds = fleet.get("spread_bound") or {}
    if bounds:
        world = fleet.get("world_us_per_step") or {}
        lines += [
            "",
            "The world's own work per step (PyBullet for every robot, timed in place), and the most spreading could "
            "gain with it on one core and the rest shared for free: "
            + ", ".join(
                f"N = {size}: {_fmt(world.get(size), 1)} µs, at most {_fmt(bound, 2)}x"
                for size, bound in bounds.items()
            ),
        ]
    return "\n".join(lines)


def table(results: dict[str, Any]) -> str:
    """The results as Markdown tables (printed, and pasted into the README): the sections run."""
    machine_info = results["machine"]
    rows = _loop_rows(results) if "lockstep" in results else []
    rows += [
        (
            f"codec {name}",
            f"{_fmt(entry['codec_ns'])} ns (json {_fmt(entry['json_ns'])} ns)",
            f"{_fmt(entry['ratio'], 1)}x",
        )
        for name, entry in (results.get("codec") or {}).items()
    ]
    lines = ["| measurement | value | ratio / detail |", "|---|---|---|"] if rows else []
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines += [""] if rows else []
    if "fleet" in results:
        lines += [fleet_table(results["fleet"]), ""]
    if "ros2_fleet" in results:
        lines += [ros2_fleet.table(results["ros2_fleet"]), ""]
    lines.append(
        f"Machine: {machine_info['cores']} cores ({machine_info['cpu']}), Python {machine_info['python']}, "
        f"zenoh {machine_info['zenoh']}, pybullet {machine_info['pybullet']}, msgspec {machine_info['msgspec']}; "
        f"load average at start {machine_info['load_average_at_start']}; {machine_info['date']}."
    )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.quick:
        args.repeats, args.warmup, args.window, args.realtime_window = 1, 0.2, 0.5, 0.5
        args.inprocess, args.codec_repeats, args.floor = 0.2, 1, 0.3
        args.fleet_sizes = QUICK_FLEET_SIZES if args.fleet_sizes == FLEET_SIZES else args.fleet_sizes
    sections = args.only or SECTIONS
    started = time.monotonic()
    results: dict[str, Any] = {"machine": machine.describe()}
    composed = composed_available()
    failures: list[str] = []
    if "loop" in sections:
        results["lockstep"] = run_lockstep(args, composed, failures)
        results["realtime"] = run_realtime(args, failures)
    if "codec" in sections:
        print("codec", flush=True)
        results["codec"] = _timed("encode + decode per type", lambda: codec.run(args.codec_repeats), failures)
        results["codec_min_ratio"] = min(entry["ratio"] for entry in results["codec"].values())
    if "fleet" in sections:
        results["fleet"] = run_fleet(args, composed, failures)
    if "ros2_fleet" in sections:
        sizes = ros2_fleet.QUICK_SIZES if args.quick else ros2_fleet.SIZES
        results["ros2_fleet"] = ros2_fleet.run_section(
            args.repeats, args.warmup, args.window, sizes, failures, args.quick
        )
    results["targets"] = check_targets({**results, "codec": {"min_ratio": results.get("codec_min_ratio")}})
    results["settings"] = {
        key: getattr(args, key)
        for key in ("repeats", "warmup", "window", "realtime_window", "inprocess", "floor", "quick", "fleet_sizes")
    }
    results["settings"]["sections"] = list(sections)
    results["failures"] = failures
    results["duration_s"] = time.monotonic() - started
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print()
    print(table(results))
    print()
    for name, check in results["targets"].items():
        verdict = {True: "met", False: "NOT met", None: "not measured"}[check["met"]]
        print(f"target {name} {'<' if name in UPPER_BOUNDS else '>='} {check['target']}: {verdict} ({check['value']})")
    for failure in failures:
        print(f"FAILED {failure}")
    print(f"\nwrote {args.out} in {results['duration_s']:.0f} s")
    return 1 if failures else 0
