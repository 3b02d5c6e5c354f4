"""The results of ``make bench`` as Markdown tables (printed at the end of a run, and pasted into
benchmarks/README.md): a row a figure of the ``lockstep``, ``realtime`` and ``codec`` sections, the
``fleet`` and ``ros2_fleet`` sections' own tables, and the machine it ran on."""

from __future__ import annotations

from typing import Any

from benchmarks import engines, fleet_section, ros2_fleet
from benchmarks.figures import cost, cpu_cost, fmt, percent, ratio
from benchmarks.realtime import RT_VARIANTS
from services.runtime.session import LOW_LATENCY_VARIABLE


def _cost_line(what: str, lockstep: dict[str, Any], cpu: dict[str, Any], loaded: str, bare: str) -> str:
    """What ``what`` (recording, the ROS 2 bridge) cost the loop of one mode, in steps/s and in CPU
    per step: the run ``loaded`` against the run ``bare``, measured in the same session."""
    steps = cost(lockstep[f"{loaded}_steps_per_s"], lockstep[f"{bare}_steps_per_s"])
    extra_cpu = cpu_cost(cpu.get(loaded), cpu.get(bare))
    return (
        f"{what} costs {fmt(steps, 1)} % of the steps/s, {fmt(extra_cpu, 1)} % CPU per step "
        f"({fmt(cpu.get(loaded))} vs {fmt(cpu.get(bare))} µs)"
    )


def _loop_rows(results: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The ``lockstep`` and ``realtime`` sections' rows of :func:`table`."""
    lockstep, realtime = results["lockstep"], results["realtime"]
    cpu = lockstep.get("cpu_us_per_step") or {}
    rows = [
        (
            "lockstep, separate processes",
            f"{fmt(lockstep['steps_per_s'])} steps/s",
            f"ratio {fmt(lockstep['ratio'], 3)}",
        ),
        (
            "lockstep, separate, `--rt` on the control path (router, motor, sim)",
            f"{fmt(lockstep.get('rt_steps_per_s'))} steps/s",
            (
                f"floor ratio {fmt(lockstep.get('rt_floor_ratio'), 3)}; CPU {fmt(cpu.get('rt'))} vs "
                f"{fmt(cpu.get('separate'))} µs per step without"
            ),
        ),
        (
            "floor: bare zenoh ping-pong between two processes",
            f"{fmt(lockstep['floor_round_trips_per_s'])} round trips/s",
            f"p50 {fmt(lockstep['floor_latency_us']['p50'])} µs; separate loop / floor = {fmt(lockstep['floor_ratio'], 3)}",
        ),
        (
            f"lockstep, separate, low-latency transport (opt-in, `{LOW_LATENCY_VARIABLE}=1`)",
            f"{fmt(lockstep['lowlatency_steps_per_s'])} steps/s",
            f"ratio {fmt(lockstep['lowlatency_ratio'], 3)}",
        ),
        (
            "lockstep, `invent up --no-record`",
            f"{fmt(lockstep['up_not_recording_steps_per_s'])} steps/s",
            f"ratio {fmt(ratio(lockstep['up_not_recording_steps_per_s'], lockstep['inprocess_steps_per_s']), 3)}",
        ),
        (
            "lockstep, `invent up` (recording run.mcap)",
            f"{fmt(lockstep['up_steps_per_s'])} steps/s",
            _cost_line("recording", lockstep, cpu, "up", "up_not_recording"),
        ),
        (
            "lockstep, composed (`invent up --composed --no-record`)",
            f"{fmt(lockstep['composed_steps_per_s'])} steps/s",
            f"ratio {fmt(lockstep['composed_ratio'], 3)}",
        ),
        (
            "lockstep, composed, `--rt`",
            f"{fmt(lockstep.get('composed_rt_steps_per_s'))} steps/s",
            f"ratio {fmt(lockstep.get('composed_rt_ratio'), 3)}",
        ),
        (
            "lockstep, composed, no intra-process delivery (`--no-intra-process`)",
            f"{fmt(lockstep.get('composed_no_intra_process_steps_per_s'))} steps/s",
            (
                f"ratio {fmt(lockstep.get('composed_no_intra_process_ratio'), 3)}; CPU "
                f"{fmt(cpu.get('composed_no_intra_process'))} vs {fmt(cpu.get('composed'))} µs per step with it"
            ),
        ),
        (
            "lockstep, composed, recording run.mcap (`invent up --composed`)",
            f"{fmt(lockstep['composed_recording_steps_per_s'])} steps/s",
            _cost_line("recording", lockstep, cpu, "composed_recording", "composed"),
        ),
        (
            "lockstep, `invent up --no-record --ros2`",
            f"{fmt(lockstep['up_ros2_steps_per_s'])} steps/s",
            _cost_line("the ROS 2 bridge", lockstep, cpu, "up_ros2", "up_not_recording"),
        ),
        (
            "lockstep, composed, `--ros2`",
            f"{fmt(lockstep['composed_ros2_steps_per_s'])} steps/s",
            _cost_line("the ROS 2 bridge", lockstep, cpu, "composed_ros2", "composed"),
        ),
        ("lockstep, in one process, no zenoh (limit)", f"{fmt(lockstep['inprocess_steps_per_s'])} steps/s", "1"),
        *(
            (
                f"lockstep, {where}, the lidar (10 Hz) and the IMU (100 Hz)",
                (
                    f"{fmt(lockstep['sensors'][where]['steps_per_s'])} vs "
                    f"{fmt(lockstep['sensors'][where]['without_steps_per_s'])} steps/s without"
                ),
                f"cost {fmt(percent(lockstep['sensors'][where]['cost']), 1)} % of the steps",
            )
            for where in ("inprocess", "separate", "composed")
            if "sensors" in lockstep
        ),
        (
            "lockstep torque latency, separate",
            f"p50 {fmt(lockstep['latency_us']['p50'])} µs",
            f"p99 {fmt(lockstep['latency_us']['p99'])} µs",
        ),
        (
            "realtime 1 kHz, separate processes",
            f"{fmt(realtime['rate_hz'])} steps/s",
            (
                f"late {fmt(percent(realtime['late_fraction']), 2)} % ({fmt(realtime.get('late_vs_floor'), 2)}x the "
                f"floor's), p99 {fmt(realtime.get('p99_vs_floor'), 2)}x the floor's"
            ),
        ),
        (
            "realtime torque latency",
            f"p50 {fmt(realtime['latency_us']['p50'])} µs",
            f"p99 {fmt(realtime['latency_us']['p99'])} µs",
        ),
        (
            "realtime floor: bare zenoh ping-pong paced at 1 kHz",
            f"p50 {fmt(realtime['floor_latency_us']['p50'])} µs, p99 {fmt(realtime['floor_latency_us']['p99'])} µs",
            f"longer than 1 ms: {fmt(percent(realtime['floor_late_fraction']), 2)} %",
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
                f"late {fmt(percent(variant['late_fraction']), 2)} %, p99 {fmt(variant['latency_us']['p99'])} µs",
                (
                    f"{fmt(variant['late_vs_floor'], 2)}x / {fmt(variant['p99_vs_floor'], 2)}x the floor's; collector "
                    f"{fmt(variant['gc_collections_per_run'])} collections and {fmt(variant['gc_pause_us_per_step'], 2)} µs "
                    f"per step in the window, longest pause since start-up {fmt(variant['gc_max_pause_us'])} µs"
                ),
            )
        )
    return rows


def table(results: dict[str, Any]) -> str:
    """The results as Markdown tables (printed, and pasted into the README): the sections run."""
    machine_info = results["machine"]
    rows = _loop_rows(results) if "lockstep" in results else []
    rows += [
        (
            f"codec {name}",
            f"{fmt(entry['codec_ns'])} ns (json {fmt(entry['json_ns'])} ns)",
            f"{fmt(entry['ratio'], 1)}x",
        )
        for name, entry in (results.get("codec") or {}).items()
    ]
    lines = ["| measurement | value | ratio / detail |", "|---|---|---|"] if rows else []
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines += [""] if rows else []
    if "fleet" in results:
        lines += [fleet_section.table(results["fleet"]), ""]
    if "ros2_fleet" in results:
        lines += [ros2_fleet.table(results["ros2_fleet"]), ""]
    if "engines" in results:
        lines += [engines.table(results["engines"]), ""]
    lines.append(
        f"Machine: {machine_info['cores']} cores ({machine_info['cpu']}), Python {machine_info['python']}, "
        f"zenoh {machine_info['zenoh']}, pybullet {machine_info['pybullet']}, msgspec {machine_info['msgspec']}; "
        f"load average at start {machine_info['load_average_at_start']}; {machine_info['date']}."
    )
    return "\n".join(lines)
