"""Where a realtime run's late steps come from: when they happen, and what the machine did then.

``python -m benchmarks.lateness [--seconds S] [--interval S] [--rt [--any-cpu]]`` runs the loop's services as
separate processes (as ``make bench``'s realtime runs do), the sim in realtime at 1 kHz, and
every ``--interval`` reads the sim's counters (``realtime_late_steps``, ``steps``) and the
machine's CPU time stolen by the hypervisor (``steal`` in ``/proc/stat``). It prints how the late
steps spread over the intervals: whether they come evenly (the loop's own cost per step, which a
change in these processes could shorten) or in bursts (moments when the processes did not run at
all), and the steal time in the intervals with late steps and in those without.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import loop
from services.runtime.session import open_session, session_config

WARMUP_S = 2.0


def stolen_seconds() -> float:
    """CPU seconds the hypervisor gave to others, all CPUs together, since boot (``/proc/stat``)."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def sample(session: Any, seconds: float, interval: float) -> list[dict[str, float]]:
    """Every ``interval`` for ``seconds``: the late steps, steps and stolen CPU seconds since the
    previous look."""
    intervals: list[dict[str, float]] = []
    previous, previous_steal = loop.sim_status(session), stolen_seconds()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        time.sleep(interval)
        status, steal = loop.sim_status(session), stolen_seconds()
        if status is None or previous is None:
            raise RuntimeError("the sim did not answer its status")
        intervals.append(
            {
                "late": status.counters.realtime_late_steps - previous.counters.realtime_late_steps,
                "steps": status.steps - previous.steps,
                "steal_ms": (steal - previous_steal) * 1000.0,
            }
        )
        previous, previous_steal = status, steal
    return intervals


def summary(intervals: Sequence[dict[str, float]]) -> dict[str, Any]:
    """How the late steps spread over the intervals, and the steal with and without them."""
    late = sorted((entry["late"] for entry in intervals), reverse=True)
    total_late, total_steps = sum(late), sum(entry["steps"] for entry in intervals)
    worst = max(1, len(late) // 20)
    with_late = [entry for entry in intervals if entry["late"] > 0]
    without_late = [entry for entry in intervals if entry["late"] == 0]

    def mean_steal(entries: Sequence[dict[str, float]]) -> float | None:
        return sum(entry["steal_ms"] for entry in entries) / len(entries) if entries else None

    return {
        "intervals": len(intervals),
        "steps": total_steps,
        "late_steps": total_late,
        "late_fraction": total_late / total_steps if total_steps else None,
        "intervals_with_late_steps": len(with_late),
        "late_share_in_worst_5_percent_of_intervals": sum(late[:worst]) / total_late if total_late else None,
        "most_late_in_one_interval": late[0] if late else 0,
        "steal_ms_per_interval_with_late_steps": mean_steal(with_late),
        "steal_ms_per_interval_without": mean_steal(without_late),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.lateness", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, metavar="S", help="wall seconds sampled")
    parser.add_argument("--interval", type=float, default=0.2, metavar="S", help="wall seconds between looks")
    parser.add_argument("--rt", action="store_true", help="--rt on the control path (router, motor, sim)")
    parser.add_argument(
        "--any-cpu", action="store_true", help='with --rt: rt.cpus = "any" (the CPUs left to the system)'
    )
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="invent-lateness-") as folder:
        control_path = [loop.RT_FLAG, *(["--set", 'rt.cpus="any"'] if args.any_cpu else [])] if args.rt else []
        run = loop.ServicesRun(["--mode", "realtime"], Path(folder), None, control_path)
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                run.start_loop(session)
                loop.wait_until_running(session, run)
                time.sleep(WARMUP_S)
                intervals = sample(session, args.seconds, args.interval)
                run.check()
        finally:
            run.stop()
    print(
        json.dumps(
            {"rt": args.rt, "any_cpu": args.any_cpu, "interval_s": args.interval, **summary(intervals)}, indent=2
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
