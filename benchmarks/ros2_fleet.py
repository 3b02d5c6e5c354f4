"""What the ROS 2 bridge of each robot of a fleet costs: ``invent up --fleet FILE --no-record`` with
and without ``--ros2``, N robots (1, 2, 4), separate processes (the default: one bridge process
per robot), runs interleaved, in the same session of ``make bench``.

The fleet is :mod:`benchmarks.fleet`'s (N robots on the empty floor, each driving the benchmark's
circle, lockstep). Each run waits until the sim is running (and, with ``--ros2``, every robot's
bridge is alive), warms up, then measures a window as :func:`benchmarks.fleet.measure_fleet` does,
and adds, with ``--ros2``, the bridges' own share, read from /proc:

- ``bridge_cpu_ms_per_robot_per_sim_s``: the bridge processes' user + system CPU over the window,
  per robot and per simulated second: what one robot's bridge costs for each second it bridges
  (100 ``/clock``, 50 each of ``odom``, ``tf`` and ``joint_states``, each built and encoded);
- ``bridge_rss_mb_per_robot``: the bridge processes' resident memory at the end of the window, per robot.

Compared with the run without bridges of the same size (medians of the repeats):

- ``cpu_us_per_robot_step``, with and without, and ``cpu_cost_percent``: how much more CPU the
  whole run took per robot-step with the bridges;
- ``steps_per_s``, with and without, and ``speed_cost_percent``: how much slower the loop stepped
  (lockstep waits for no bridge, but the bridges share the machine's cores with the loop).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks import fleet as fleet_bench
from benchmarks import loop
from schemas.keys import Keys, Service
from services.runtime.session import open_session, session_config

SIZES = (1, 2, 4)
QUICK_SIZES = (1,)


@dataclass(frozen=True)
class BridgeRun:
    robots: int
    ros2: bool
    steps_per_s: float
    cpu_us_per_robot_step: float
    late_fraction: float
    bridge_cpu_ms_per_robot_per_sim_s: float | None
    bridge_rss_mb_per_robot: float | None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class BridgeFleetRun(fleet_bench.FleetUpRun):
    """``invent up --fleet`` of ``count`` robots, separate processes, with ``--ros2`` or without."""

    def __init__(self, count: int, ros2: bool, directory: Path) -> None:
        super().__init__(count, "separate", directory, [loop.ROS2_FLAG] if ros2 else [])

    def bridge_pids(self) -> list[int]:
        """The bridge children (``python -m services.cli ros2 ...``)."""
        return [
            pid
            for pid in fleet_bench._children(self.process.pid)
            if "services.cli" in (argv := fleet_bench._argv(pid))
            and argv[argv.index("services.cli") + 1 :][:1] == [str(Service.ROS2)]
        ]


def _rss_mb(pids: list[int]) -> float:
    """Resident memory of ``pids``, MB, from /proc."""
    total_kb = 0
    for pid in pids:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total_kb += int(line.split()[1])
    return total_kb / 1000.0


def _wait_bridges(session: Any, run: BridgeFleetRun, names: list[str]) -> None:
    deadline = time.monotonic() + fleet_bench.START_TIMEOUT_S
    while True:
        alive = {str(r.ok.key_expr) for r in session.liveliness().get("invent/*/ros2/alive", timeout=1.0) if r.ok}
        if alive >= {Keys(name).alive(Service.ROS2) for name in names} and len(run.bridge_pids()) == len(names):
            return
        run.check()
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for the bridges:\n{run.output()}")
        time.sleep(loop.POLL_S)


def measure(count: int, ros2: bool, warmup_s: float, window_s: float) -> BridgeRun:
    """One run of ``count`` robots, with the bridges or without, measured over ``window_s``."""
    names = fleet_bench.robot_names(count)
    with tempfile.TemporaryDirectory(prefix="invent-bench-ros2-fleet-") as folder:
        run = BridgeFleetRun(count, ros2, Path(folder))
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                fleet_bench._wait_running(session, run, names[0])
                if ros2:
                    _wait_bridges(session, run, names)
                time.sleep(warmup_s)
                bridges = run.bridge_pids()
                first_all = [fleet_bench._status(session, name) for name in names]
                first_wall, first_cpu = time.monotonic(), loop.cpu_seconds(run.pids)
                first_bridges = loop.cpu_seconds(bridges) if bridges else 0.0
                time.sleep(window_s)
                last_all = [fleet_bench._status(session, name) for name in names]
                last_wall, last_cpu = time.monotonic(), loop.cpu_seconds(run.pids)
                last_bridges = loop.cpu_seconds(bridges) if bridges else 0.0
                rss = _rss_mb(bridges) if bridges else None
                run.check()
        finally:
            run.stop()
    first, last = first_all[0], last_all[0]
    if first is None or last is None:
        raise RuntimeError("the fleet's sim did not answer its status")
    steps = last.steps - first.steps
    simulated_s = last.sim_time_s - first.sim_time_s
    late = fleet_bench._late(last_all) - fleet_bench._late(first_all)
    return BridgeRun(
        robots=count,
        ros2=ros2,
        steps_per_s=steps / (last_wall - first_wall),
        cpu_us_per_robot_step=(last_cpu - first_cpu) / (steps * count) * 1e6 if steps else float("inf"),
        late_fraction=late / (steps * count) if steps else 1.0,
        bridge_cpu_ms_per_robot_per_sim_s=(last_bridges - first_bridges) / count / simulated_s * 1e3
        if ros2 and simulated_s > 0
        else None,
        bridge_rss_mb_per_robot=rss / count if rss is not None else None,
    )


def _median(values: list[float | None]) -> float | None:
    present = sorted(value for value in values if value is not None)
    return present[len(present) // 2] if present else None


def summarize(runs: dict[int, dict[bool, list[BridgeRun]]]) -> dict[str, Any]:
    """Per size: the medians with and without the bridges, and what the bridges cost."""
    summary: dict[str, Any] = {}
    for size, by_mode in runs.items():
        with_bridges, without = by_mode.get(True, []), by_mode.get(False, [])
        speed = _median([run.steps_per_s for run in with_bridges])
        bare_speed = _median([run.steps_per_s for run in without])
        cpu = _median([run.cpu_us_per_robot_step for run in with_bridges])
        bare_cpu = _median([run.cpu_us_per_robot_step for run in without])
        summary[str(size)] = {
            "steps_per_s": speed,
            "steps_per_s_without": bare_speed,
            "speed_cost_percent": None if not (speed and bare_speed) else (1.0 - speed / bare_speed) * 100.0,
            "cpu_us_per_robot_step": cpu,
            "cpu_us_per_robot_step_without": bare_cpu,
            "cpu_cost_percent": None if not (cpu and bare_cpu) else (cpu / bare_cpu - 1.0) * 100.0,
            "bridge_cpu_ms_per_robot_per_sim_s": _median([r.bridge_cpu_ms_per_robot_per_sim_s for r in with_bridges]),
            "bridge_rss_mb_per_robot": _median([run.bridge_rss_mb_per_robot for run in with_bridges]),
            "late_fraction": _median([run.late_fraction for run in with_bridges]),
            "runs": [run.as_dict() for run in (*with_bridges, *without)],
        }
    return summary


def _figure(entry: dict[str, Any], key: str, digits: int = 0) -> str:
    value = entry.get(key)
    return "n/a" if value is None else f"{value:,.{digits}f}"


def _compared(entry: dict[str, Any], key: str, cost: str, sign: str) -> str:
    """``without → with (cost %)``, or the figure with the bridges alone when there is no run without."""
    if entry.get(f"{key}_without") is None:
        return _figure(entry, key)
    return f"{_figure(entry, f'{key}_without')} → {_figure(entry, key)} ({sign}{_figure(entry, cost, 1)} %)"


def table(section: dict[str, Any]) -> str:
    """The section as the Markdown table of benchmarks/README.md."""
    lines = [
        "| robots | steps/s without → with | CPU µs per robot-step without → with | bridge CPU per robot | bridge memory per robot |",
        "|---|---|---|---|---|",
    ]
    for size, entry in section.items():
        lines.append(
            f"| {size} | {_compared(entry, 'steps_per_s', 'speed_cost_percent', '')} "
            f"| {_compared(entry, 'cpu_us_per_robot_step', 'cpu_cost_percent', '+')} "
            f"| {_figure(entry, 'bridge_cpu_ms_per_robot_per_sim_s', 1)} ms per simulated s "
            f"| {_figure(entry, 'bridge_rss_mb_per_robot')} MB |"
        )
    return "\n".join(lines)


def run_section(
    repeats: int, warmup_s: float, window_s: float, sizes: tuple[int, ...], failures: list[str], quick: bool = False
) -> dict:
    """Every size with and without the bridges, ``repeats`` times, interleaved; a run that fails is
    named in ``failures`` and left out of the medians. ``quick`` (``--quick``: that everything runs):
    only the runs with the bridges, the others being the ``fleet`` section's runs."""
    runs: dict[int, dict[bool, list[BridgeRun]]] = {size: {True: [], False: []} for size in sizes}
    for repeat in range(repeats):
        for size in sizes:
            for ros2 in (True,) if quick else (False, True):
                what = (
                    f"ros2 fleet, run {repeat + 1} of {repeats}: {size} robots, {'with' if ros2 else 'without'} bridges"
                )
                print(what, flush=True)
                try:
                    runs[size][ros2].append(measure(size, ros2, warmup_s, window_s))
                except (RuntimeError, OSError) as error:
                    failures.append(f"{what}: {error}")
    return summarize(runs)


def main() -> int:
    """``python -m benchmarks.ros2_fleet [--quick]``: this section alone, printed as JSON and a table
    (``make bench`` runs it as the section ``ros2_fleet``)."""
    quick = "--quick" in sys.argv[1:]
    failures: list[str] = []
    repeats, warmup, window = (1, 0.5, 1.0) if quick else (3, 1.0, 4.0)
    section = run_section(repeats, warmup, window, QUICK_SIZES if quick else SIZES, failures, quick)
    print(json.dumps(section, indent=2))
    print(table(section))
    for failure in failures:
        print(f"FAILED {failure}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
