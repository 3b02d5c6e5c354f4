"""The ``realtime`` section of ``make bench``: the loop's processes with the sim in realtime mode at
1 kHz: achieved rate, late fraction, torque latency, with and without ``--rt`` on the control path
(:data:`RT_VARIANTS`); and the floor ping-pong paced at 1 kHz (``floor_*``): its round trips'
latency and the fraction longer than a period, what the bare exchange would count late. Each
figure is the median over the repeats.
"""

from __future__ import annotations

import argparse
import functools
from typing import Any

from benchmarks import floor, loop
from benchmarks.figures import cpu_per_step, keep, median, ratio, timed

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
    late = median([run.late_fraction for run in runs])
    p99 = median([run.latency_us["p99"] for run in runs])
    gc_runs = [run.gc for run in runs if run.gc]
    return {
        "late_fraction": late,
        "missing_fraction": median([run.missing_fraction for run in runs]),
        "latency_us": {
            quantile: median([run.latency_us[quantile] for run in runs]) for quantile in ("p50", "p99", "max")
        },
        "late_vs_floor": ratio(late, floor_late),
        "p99_vs_floor": ratio(p99, floor_p99),
        "cpu_us_per_step": cpu_per_step(runs),
        "gc_pause_us_per_step": median([entry["pause_us_per_step"] for entry in gc_runs]),
        "gc_max_pause_us": median([entry["max_pause_us_since_start"] for entry in gc_runs]),
        "gc_collections_per_run": median([sum(entry["collections"]) for entry in gc_runs]),
        "sched": gc_runs[-1]["sched"] if gc_runs else None,
        "cpus": gc_runs[-1].get("cpus") if gc_runs else None,
        "runs": [run.as_dict() for run in runs],
    }


def run_section(args: argparse.Namespace, failures: list[str]) -> dict[str, Any]:
    runs: list[loop.LoopResult] = []
    floors: list[dict[str, float]] = []
    variants: dict[str, list[loop.LoopResult]] = {name: [] for name in RT_VARIANTS}
    for repeat in range(args.repeats):
        print(f"realtime, 1 kHz, run {repeat + 1} of {args.repeats}", flush=True)
        floors.append(
            timed(
                "zenoh ping-pong paced at 1 kHz (floor)",
                lambda: floor.measure(args.realtime_window, f"tcp/127.0.0.1:{loop.free_port()}", REALTIME_HZ),
                failures,
            )
        )
        keep(
            runs,
            timed(
                "separate processes",
                lambda: loop.measure_services(["--mode", "realtime"], args.warmup, args.realtime_window),
                failures,
            ),
        )
        for name, flags in RT_VARIANTS.items():
            keep(
                variants[name],
                timed(
                    f"separate processes, {' '.join(flags)}",
                    functools.partial(
                        loop.measure_services, ["--mode", "realtime"], args.warmup, args.realtime_window, None, flags
                    ),
                    failures,
                ),
            )
    floors = [value for value in floors if value is not None]
    floor_late = median([value["longer_than_period_fraction"] for value in floors])
    floor_p99 = median([value["p99_us"] for value in floors])
    return {
        **{name: _realtime_summary(results, floor_late, floor_p99) for name, results in variants.items()},
        "late_vs_floor": ratio(median([run.late_fraction for run in runs]), floor_late),
        "p99_vs_floor": ratio(median([run.latency_us["p99"] for run in runs]), floor_p99),
        "rate_hz": median([run.steps_per_s for run in runs]),
        "floor_latency_us": {
            quantile: median([value[f"{quantile}_us"] for value in floors]) for quantile in ("p50", "p99", "max")
        },
        "floor_late_fraction": median([value["longer_than_period_fraction"] for value in floors]),
        "real_time_factor": median([run.sim_seconds_per_s for run in runs]),
        "late_fraction": median([run.late_fraction for run in runs]),
        "missing_fraction": median([run.missing_fraction for run in runs]),
        "latency_us": {
            quantile: median([run.latency_us[quantile] for run in runs]) for quantile in ("p50", "p99", "max")
        },
        "runs": [run.as_dict() for run in runs],
        "floor_runs": floors,
    }
