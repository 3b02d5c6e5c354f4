"""The ``lockstep`` section of ``make bench``: steps per second of the real loop (router, motor,
odometry, localization, sim and drive, each its own process, started as ``invent up`` starts them),
of ``invent up`` itself recording its run.mcap and with ``--no-record``, of the composed loop
(``invent up --composed --no-record``, and recording, as plain ``invent up --composed``) and of the
in-process limit, with their ratios and what recording costs in each mode; what the ROS 2 bridge
beside the loop (``--ros2``) costs, separate and composed; the step exchange latency measured by the
sim; and the floor zenoh sets (``floor_*``): a bare zenoh-python ping-pong between two processes
configured as the services are (``benchmarks/floor.py``), and the separate-process loop's steps per
second against it (``floor_ratio``): one lockstep step needs at least one such round trip.

Runs are interleaved with the in-process limit, so a ratio compares numbers taken under the same
machine load; each figure is the median over the repeats.
"""

from __future__ import annotations

import argparse
from typing import Any

from benchmarks import floor, loop
from benchmarks.figures import cpu_per_step, keep, median, ratio, timed
from services.runtime.session import LOW_LATENCY_VARIABLE


def _loop_summary(runs: list[loop.LoopResult]) -> dict[str, Any]:
    return {
        "steps_per_s": median([run.steps_per_s for run in runs]),
        "latency_us": {
            "p50": median([run.latency_us["p50"] for run in runs]),
            "p99": median([run.latency_us["p99"] for run in runs]),
        },
        "late_fraction": median([run.late_fraction for run in runs]),
    }


def _sensors_cost(
    inprocess: list[float],
    inprocess_bare: list[float],
    separate: list[loop.LoopResult],
    separate_bare: list[loop.LoopResult],
    composed: list[loop.LoopResult],
    composed_bare: list[loop.LoopResult],
) -> dict[str, Any]:
    """What the lidar (10 Hz) and the IMU (100 Hz) cost the loop: steps per second with and without
    them, and the share of the steps they take (1 - with / without), in-process, separate, composed."""
    figures: dict[str, Any] = {}
    pairs = (
        ("inprocess", inprocess, [value for value in inprocess_bare if value is not None]),
        ("separate", [run.steps_per_s for run in separate], [run.steps_per_s for run in separate_bare]),
        ("composed", [run.steps_per_s for run in composed], [run.steps_per_s for run in composed_bare]),
    )
    for name, with_sensors, without in pairs:
        steps, bare = median(with_sensors), median(without)
        cost = None if steps is None or not bare else 1.0 - steps / bare
        figures[name] = {"steps_per_s": steps, "without_steps_per_s": bare, "cost": cost}
    return figures


def run_section(args: argparse.Namespace, composed: bool, failures: list[str]) -> dict[str, Any]:
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
    inprocess_bare: list[float] = []
    separate_bare: list[loop.LoopResult] = []
    together_bare: list[loop.LoopResult] = []
    for repeat in range(args.repeats):
        print(f"lockstep, run {repeat + 1} of {args.repeats}", flush=True)
        inprocess.append(timed("in-process limit", lambda: loop.inprocess_steps_per_s(args.inprocess), failures))
        floors.append(
            timed(
                "zenoh ping-pong floor",
                lambda: floor.measure(args.floor, f"tcp/127.0.0.1:{loop.free_port()}"),
                failures,
            )
        )
        keep(
            separate,
            timed("separate processes", lambda: loop.measure_services([], args.warmup, args.window), failures),
        )
        inprocess_bare.append(
            timed("in-process, no sensors", lambda: loop.inprocess_steps_per_s(args.inprocess, False), failures)
        )
        keep(
            separate_bare,
            timed(
                "separate, no sensors",
                lambda: loop.measure_services(loop.NO_SENSORS_FLAGS, args.warmup, args.window),
                failures,
            ),
        )
        keep(
            separate_rt,
            timed(
                "separate, --rt on the control path",
                lambda: loop.measure_services([], args.warmup, args.window, None, [loop.RT_FLAG]),
                failures,
            ),
        )
        keep(
            low_latency,
            timed(
                "separate, low-latency transport",
                lambda: loop.measure_services([], args.warmup, args.window, {LOW_LATENCY_VARIABLE: "1"}),
                failures,
            ),
        )
        keep(with_up, timed("invent up (recording)", lambda: loop.measure_up([], args.warmup, args.window), failures))
        keep(
            up_not_recording,
            timed(
                "invent up --no-record",
                lambda: loop.measure_up([loop.NO_RECORD_FLAG], args.warmup, args.window),
                failures,
            ),
        )
        keep(
            up_ros2,
            timed(
                "invent up --no-record --ros2",
                lambda: loop.measure_up([loop.NO_RECORD_FLAG, loop.ROS2_FLAG], args.warmup, args.window),
                failures,
            ),
        )
        if composed:
            keep(
                together_ros2,
                timed(
                    "composed, --ros2",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.ROS2_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            keep(
                together,
                timed(
                    "composed",
                    lambda: loop.measure_up([loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG], args.warmup, args.window),
                    failures,
                ),
            )
            keep(
                together_bare,
                timed(
                    "composed, no sensors",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, *loop.NO_SENSORS_FLAGS], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            keep(
                together_rt,
                timed(
                    "composed, --rt",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.RT_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            keep(
                together_no_intra,
                timed(
                    "composed, no intra-process delivery",
                    lambda: loop.measure_up(
                        [loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, loop.NO_INTRA_PROCESS_FLAG], args.warmup, args.window
                    ),
                    failures,
                ),
            )
            keep(
                together_recording,
                timed(
                    "composed, recording",
                    lambda: loop.measure_up([loop.COMPOSED_FLAG], args.warmup, args.window),
                    failures,
                ),
            )
    inprocess = [value for value in inprocess if value is not None]
    floors = [value for value in floors if value is not None]
    floor_rate = median([value["round_trips_per_s"] for value in floors])

    limit = median(inprocess)
    alone, shared = _loop_summary(separate), _loop_summary(together) if together else None
    return {
        "steps_per_s": alone["steps_per_s"],
        "inprocess_steps_per_s": limit,
        "ratio": ratio(alone["steps_per_s"], limit),
        "floor_round_trips_per_s": floor_rate,
        "floor_ratio": ratio(alone["steps_per_s"], floor_rate),
        "floor_latency_us": {
            quantile: median([value[f"{quantile}_us"] for value in floors]) for quantile in ("p50", "p99")
        },
        "latency_us": alone["latency_us"],
        "late_fraction": alone["late_fraction"],
        "rt_steps_per_s": median([run.steps_per_s for run in separate_rt]),
        "rt_floor_ratio": ratio(median([run.steps_per_s for run in separate_rt]), floor_rate),
        "rt_latency_us": _loop_summary(separate_rt)["latency_us"] if separate_rt else None,
        "up_steps_per_s": median([run.steps_per_s for run in with_up]),
        "up_not_recording_steps_per_s": median([run.steps_per_s for run in up_not_recording]),
        "lowlatency_steps_per_s": median([run.steps_per_s for run in low_latency]),
        "lowlatency_ratio": ratio(median([run.steps_per_s for run in low_latency]), limit),
        "lowlatency_latency_us": _loop_summary(low_latency)["latency_us"],
        "composed_steps_per_s": shared["steps_per_s"] if shared else None,
        "composed_ratio": ratio(shared["steps_per_s"], limit) if shared else None,
        "composed_latency_us": shared["latency_us"] if shared else None,
        "composed_rt_steps_per_s": median([run.steps_per_s for run in together_rt]),
        "composed_rt_ratio": ratio(median([run.steps_per_s for run in together_rt]), limit),
        "composed_no_intra_process_steps_per_s": median([run.steps_per_s for run in together_no_intra]),
        "composed_no_intra_process_ratio": ratio(median([run.steps_per_s for run in together_no_intra]), limit),
        "composed_recording_steps_per_s": median([run.steps_per_s for run in together_recording]),
        "up_ros2_steps_per_s": median([run.steps_per_s for run in up_ros2]),
        "composed_ros2_steps_per_s": median([run.steps_per_s for run in together_ros2]),
        "cpu_us_per_step": {
            "separate": cpu_per_step(separate),
            "rt": cpu_per_step(separate_rt),
            "up": cpu_per_step(with_up),
            "up_not_recording": cpu_per_step(up_not_recording),
            "composed": cpu_per_step(together),
            "composed_rt": cpu_per_step(together_rt),
            "composed_no_intra_process": cpu_per_step(together_no_intra),
            "composed_recording": cpu_per_step(together_recording),
            "up_ros2": cpu_per_step(up_ros2),
            "composed_ros2": cpu_per_step(together_ros2),
        },
        "sensors": _sensors_cost(inprocess, inprocess_bare, separate, separate_bare, together, together_bare),
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
