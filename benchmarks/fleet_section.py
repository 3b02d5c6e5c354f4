"""The ``fleet`` section of ``make bench``: how the loop scales with the robots of one world
(``invent up --fleet --no-record``, N = 1, 2, 4, 8, separate, composed in one process and composed
over one process per core): steps/s, CPU per robot-step, the sim's share of the CPU, and the most
spreading the composed fleet over the cores could gain (benchmarks/fleet.py measures each run).
"""

from __future__ import annotations

import argparse
import functools
import os
from typing import Any

from benchmarks import fleet as fleet_bench
from benchmarks import loop
from benchmarks.figures import fmt, median, percent, ratio, timed

FLEET_MODES = tuple(fleet_bench.MODES)
FLEET_FIELDS = (
    "steps_per_s",
    "robot_steps_per_s",
    "cpu_us_per_robot_step",
    "sim_share",
    "late_fraction",
    "cpu_cores",
)


def run_section(args: argparse.Namespace, composed: bool, failures: list[str]) -> dict[str, Any]:
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
            world_us = timed(
                f"{size} robot{'s' * (size > 1)}, the world's own work in place",
                functools.partial(fleet_bench.world_step_us, size, args.inprocess),
                failures,
            )
            if world_us is not None:
                world[str(size)].append(world_us)
            for mode in modes:
                result = timed(
                    f"{size} robot{'s' * (size > 1)}, {mode}",
                    functools.partial(fleet_bench.measure_fleet, size, mode, args.warmup, args.window),
                    failures,
                )
                if result is not None:
                    runs[mode][str(size)].append(result.as_dict())
    medians = {
        mode: {
            size: {field: median([run[field] for run in sized]) for field in FLEET_FIELDS}
            for size, sized in by_size.items()
        }
        for mode, by_size in runs.items()
    }
    one, spread = medians.get("composed", {}), medians.get("composed_workers", {})
    world_us = {size: median(values) for size, values in world.items()}
    cores = os.cpu_count() or 1
    return {
        "sizes": list(args.fleet_sizes),
        **medians,
        "workers_speedup": {
            size: ratio(spread.get(size, {}).get("robot_steps_per_s"), one.get(size, {}).get("robot_steps_per_s"))
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


def table(fleet: dict[str, Any]) -> str:
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
            share = "n/a (composed)" if mode != "separate" else f"{fmt(percent(entry['sim_share']))} %"
            lines.append(
                f"| {size} | {mode} | {fmt(entry['steps_per_s'])} | {fmt(entry['robot_steps_per_s'])} | "
                f"{fmt(entry['cpu_us_per_robot_step'])} | {share} | {fmt(entry['cpu_cores'], 2)} |"
            )
    speedups = fleet.get("workers_speedup") or {}
    if speedups:
        lines += [
            "",
            "Composed over one process per core (`--workers` the cores) against one process (`--workers 1`, the default), robot-steps/s: "
            + ", ".join(f"N = {size}: {fmt(speedup, 2)}x" for size, speedup in speedups.items()),
        ]
    bounds = fleet.get("spread_bound") or {}
    if bounds:
        world = fleet.get("world_us_per_step") or {}
        lines += [
            "",
            "The world's own work per step (PyBullet for every robot, timed in place), and the most spreading could "
            "gain with it on one core and the rest shared for free: "
            + ", ".join(
                f"N = {size}: {fmt(world.get(size), 1)} µs, at most {fmt(bound, 2)}x" for size, bound in bounds.items()
            ),
        ]
    return "\n".join(lines)
