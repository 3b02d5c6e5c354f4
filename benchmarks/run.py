"""``make bench``: measure, print a table, write ``benchmarks/results/latest.json``.

The command line: which sections run and for how long (``--quick``: tiny durations, that everything
runs), then the results file, the table (benchmarks/table.py) and the targets (benchmarks/targets.py).
Sections (benchmarks/README.md explains each number and what was tried to push them):

- ``lockstep`` (benchmarks/lockstep.py): steps per second of the real loop, separate processes,
  ``invent up`` recording or not, composed, with ``--rt`` and ``--ros2``, against the in-process
  limit and the floor zenoh sets (``floor_*``, benchmarks/floor.py); the step exchange latency.
- ``realtime`` (benchmarks/realtime.py): the same processes with the sim in realtime mode at 1 kHz,
  with and without ``--rt``, against the floor ping-pong paced at 1 kHz.
- ``codec`` (benchmarks/codec.py): ns per encode + decode per message type, the project's codec
  against stdlib json.
- ``fleet`` (benchmarks/fleet_section.py, each run measured by benchmarks/fleet.py): how the loop
  scales with the robots of one world (``invent up --fleet --no-record``, N = 1, 2, 4, 8, separate
  and composed): steps/s, CPU per robot-step, the sim's share of the CPU.
- ``ros2_fleet`` (benchmarks/ros2_fleet.py): what the ROS 2 bridge of each robot of a fleet costs
  (``invent up --fleet --no-record`` with and without ``--ros2``, N = 1, 2, 4): the bridges' CPU per
  robot per simulated second and memory per robot, the loop's steps/s and CPU per robot-step with
  and without.
- ``engines`` (benchmarks/engines.py): the real-time factor of the lockstep square on PyBullet and
  on the kinematic engine (``--engine``), separate and composed, and kinematic / PyBullet; each
  engine's own µs per step in-process.
- ``navigation`` (benchmarks/navigation.py): what the drive's navigation costs its thread, in ms and as
  a share of the lidar's period: a costmap update per scan, a plan across a building of rooms (pure
  Python A* and smoothing), and pyastar2d's search and plans against it where pyastar2d is installed.
- ``localization`` (benchmarks/localization.py): the particle filter's update per scan with the default
  particles (converged, and at ``max_particles``) and a map made from a run per simulated minute, each
  as a share of the lidar's period.
- ``machine`` (benchmarks/machine.py): where it ran.

Loop figures are medians over ``--repeats`` runs (lockstep runs interleaved with the in-process
limit, so a ratio compares numbers taken under the same machine load).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import (
    codec,
    engines,
    fleet_section,
    localization,
    lockstep,
    loop,
    machine,
    navigation,
    realtime,
    ros2_fleet,
)
from benchmarks.figures import timed
from benchmarks.table import table
from benchmarks.targets import check_targets, verdicts

RESULTS = Path(__file__).resolve().parent / "results" / "latest.json"


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


SECTIONS = ("loop", "codec", "fleet", "ros2_fleet", "engines", "navigation", "localization")
"""``loop``: the ``lockstep`` and ``realtime`` sections; ``fleet``: benchmarks/fleet.py; ``ros2_fleet``:
the ROS 2 bridge of each robot of a fleet, benchmarks/ros2_fleet.py; ``engines``: the lockstep square
on PyBullet and on the kinematic engine, benchmarks/engines.py; ``navigation``: the costmap's update
and the planner, in-process, benchmarks/navigation.py; ``localization``: the particle filter's update and
a map from a run, in-process, benchmarks/localization.py."""
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
        results["lockstep"] = lockstep.run_section(args, composed, failures)
        results["realtime"] = realtime.run_section(args, failures)
    if "codec" in sections:
        print("codec", flush=True)
        results["codec"] = timed("encode + decode per type", lambda: codec.run(args.codec_repeats), failures)
        results["codec_min_ratio"] = min(entry["ratio"] for entry in results["codec"].values())
    if "fleet" in sections:
        results["fleet"] = fleet_section.run_section(args, composed, failures)
    if "ros2_fleet" in sections:
        sizes = ros2_fleet.QUICK_SIZES if args.quick else ros2_fleet.SIZES
        results["ros2_fleet"] = ros2_fleet.run_section(
            args.repeats, args.warmup, args.window, sizes, failures, args.quick
        )
    if "engines" in sections:
        results["engines"] = engines.run_section(args, failures)
    if "navigation" in sections:
        results["navigation"] = navigation.run_section(args, failures)
    if "localization" in sections:
        results["localization"] = localization.run_section(args, failures)
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
    if "navigation" in results:
        print()
        print(navigation.table(results["navigation"]))
    if "localization" in results:
        print()
        print(localization.table(results["localization"]))
    print()
    for line in verdicts(results["targets"]):
        print(line)
    for failure in failures:
        print(f"FAILED {failure}")
    print(f"\nwrote {args.out} in {results['duration_s']:.0f} s")
    return 1 if failures else 0
