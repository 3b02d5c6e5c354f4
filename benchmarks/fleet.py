"""How the loop scales with the fleet: ``invent up --fleet FILE --no-record`` with N robots in one
world, as separate processes and ``--composed``.

Each run writes a fleet file of N robots (``rh0`` .. ``rh{N-1}``, started ``ROBOT_SPACING_M`` apart
along y on the empty floor, so their 1 m circles never meet), each driving the lockstep benchmark's
constant-velocity circle (``benchmarks/loop.py``, long enough never to end), starts ``invent up``
on a free port, waits until the sim is running, warms up, then reads the sim's status (of the first
robot: its ``steps`` are the world's, one step moves every robot) at the start and the end of a
window, as :func:`benchmarks.loop._measure` does:

- ``steps_per_s``: world steps stepped / wall seconds between the two replies;
- ``robot_steps_per_s``: ``steps_per_s`` × N, the work done;
- ``cpu_us_per_robot_step``: user + system CPU of ``up``'s whole process tree over the window /
  (steps × N), from /proc;
- ``cpu_cores``: the tree's CPU seconds per wall second, how many cores the run kept busy;
- ``sim_share``: the sim process's CPU / the tree's, separate only. Composed, every service of every
  robot runs in ``up``'s one process and on the sim's one thread (services/launch/composition.py: the
  sim's lockstep wait spins the shared executor that serves the motors, odometries, drives and
  localizations), so neither the process nor the thread separates the sim's own work from the
  services'; the share is null there (:data:`COMPOSED_SIM_SHARE_NOTE`).

``late_fraction`` sums every robot's ``missing_torques`` over the window per robot-step (a lockstep
step waits for its torque while the motor control lives; one that went on without it shows here, and
its speed would say nothing about the stack).

``python -m benchmarks.fleet RESULTS.json PLOT.png`` draws a results file's ``fleet`` section
(benchmarks/fleet-scaling.png is drawn so).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from benchmarks import loop
from schemas.keys import Keys
from schemas.status import SimStatus
from services.runtime.session import open_session, session_config

ROBOT_NAME_PREFIX = "rh"
ROBOT_SPACING_M = 3.0
"""Start y of robot i is ``ROBOT_SPACING_M * i``: each circle (1 m radius, to the left) spans y to y + 2 m."""
WORLD = "empty"
START_TIMEOUT_S = 180.0
"""Eight robots as separate processes are 33 Python processes starting on two cores."""
STOP_TIMEOUT_S = 60.0
MODES: dict[str, list[str]] = {
    "separate": [],
    "composed": [loop.COMPOSED_FLAG, "--workers", "1"],
    "composed_workers": [loop.COMPOSED_FLAG, "--workers", str(os.cpu_count() or 1)],
}
"""``invent up --fleet`` flags of each mode: separate processes; composed in one process (the
default); composed with the robots spread over as many processes as the machine has cores."""
COMPOSED_SIM_SHARE_NOTE = (
    "composed: every service of every robot runs in one process on the sim's thread (the sim's lockstep wait "
    "serves the shared executor), so the sim's own CPU is not separable by process or thread: null"
)


@dataclass(frozen=True)
class FleetResult:
    robots: int
    mode: str
    steps_per_s: float
    steps: int
    window_s: float
    cpu_us_per_robot_step: float
    sim_share: float | None
    """The sim process's CPU / the whole tree's over the window; None composed."""
    late_fraction: float
    """Late + missing torques of every robot over the window, per robot-step."""
    cpu_cores: float
    """The tree's CPU seconds per wall second over the window: how many of the machine's cores the
    run kept busy (below 1 composed: its one loop thread waited for something other than CPU)."""

    @property
    def robot_steps_per_s(self) -> float:
        return self.steps_per_s * self.robots

    def as_dict(self) -> dict[str, Any]:
        return {
            "robots": self.robots,
            "mode": self.mode,
            "steps_per_s": self.steps_per_s,
            "robot_steps_per_s": self.robot_steps_per_s,
            "cpu_us_per_robot_step": self.cpu_us_per_robot_step,
            "sim_share": self.sim_share,
            "late_fraction": self.late_fraction,
            "cpu_cores": self.cpu_cores,
            "steps": self.steps,
            "window_s": self.window_s,
        }


def robot_names(count: int) -> list[str]:
    return [f"{ROBOT_NAME_PREFIX}{index}" for index in range(count)]


def fleet_file(directory: Path, count: int) -> Path:
    """A fleet of ``count`` robots on the empty floor, each driving the benchmark's circle."""
    scenario = loop.scenario_file(directory)
    lines = [f"world = {json.dumps(WORLD)}"]
    for index, name in enumerate(robot_names(count)):
        lines += [
            "",
            "[[robots]]",
            f"name = {json.dumps(name)}",
            f"start = {{ x = 0.0, y = {ROBOT_SPACING_M * index}, theta = 0.0 }}",
            f"scenario = {json.dumps(str(scenario))}",
        ]
    path = directory / f"bench_fleet_{count}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``, from /proc (Linux)."""
    children = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            parent = int(Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):  # it ended meanwhile
            continue
        if parent == pid:
            children.append(int(entry))
    return children


def _argv(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return []


class FleetUpRun(loop.UpRun):
    """One ``invent up --fleet`` in the background (its working directory a temporary folder, so
    the motors' state files land there), its output in a log file; watched and stopped as
    :class:`benchmarks.loop.UpRun` is."""

    def __init__(self, count: int, mode: str, directory: Path, extra_flags: Sequence[str] = ()) -> None:
        # Not UpRun.__init__: the same fields, for a fleet's argv and working directory.

        self.count = count
        self.composed = mode != "separate"
        self.endpoint = f"tcp/127.0.0.1:{loop.free_port()}"
        self.log_path = directory / f"up-fleet-{mode}-{count}-{time.monotonic_ns()}.log"
        argv = [
            sys.executable, "-m", "services.cli", "up",
            "--fleet", str(fleet_file(directory, count)),
            "--listen", self.endpoint,
            loop.NO_RECORD_FLAG,
            "--log-level", "warning",
            *MODES[mode],
            *extra_flags,
        ]  # fmt: skip
        self._log = self.log_path.open("w")
        self.process = subprocess.Popen(argv, cwd=directory, stdout=self._log, stderr=subprocess.STDOUT)

    def sim_pid(self) -> int | None:
        """The sim child's pid (separate processes: ``python -m services.cli sim ...``); None composed."""
        if self.composed:
            return None
        for pid in _children(self.process.pid):
            argv = _argv(pid)
            if "services.cli" in argv and argv[argv.index("services.cli") + 1 :][:1] == ["sim"]:
                return pid
        return None


def _status(session: zenoh.Session, name: str) -> SimStatus | None:
    return loop.sim_status(session, Keys(name))


def _wait_running(session: zenoh.Session, run: FleetUpRun, first: str) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while loop._state(_status(session, first)) != "running":
        run.check()
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for the fleet's sim running:\n{run.output()}")
        time.sleep(loop.POLL_S)


def _late(statuses: Sequence[SimStatus | None]) -> int:
    return sum(status.counters.missing_torques for status in statuses if status is not None)


def measure_fleet(count: int, mode: str, warmup_s: float, window_s: float) -> FleetResult:
    """Run ``invent up --fleet`` of ``count`` robots in ``mode`` (:data:`MODES`) and measure over ``window_s``."""
    names = robot_names(count)
    composed = mode != "separate"
    with tempfile.TemporaryDirectory(prefix="invent-bench-fleet-") as folder:
        run = FleetUpRun(count, mode, Path(folder))
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                _wait_running(session, run, names[0])
                time.sleep(warmup_s)
                sim_pid = run.sim_pid()
                if not composed and sim_pid is None:
                    raise RuntimeError(f"no sim process under invent up (pid {run.process.pid})")
                sim_cpu = (lambda: loop.cpu_seconds([sim_pid])) if sim_pid is not None else (lambda: 0.0)
                first_all = [_status(session, name) for name in names[1:]]
                first, first_wall = _status(session, names[0]), time.monotonic()
                first_cpu, first_sim_cpu = loop.cpu_seconds(run.pids), sim_cpu()
                time.sleep(window_s)
                last, last_wall = _status(session, names[0]), time.monotonic()
                last_cpu, last_sim_cpu = loop.cpu_seconds(run.pids), sim_cpu()
                last_all = [_status(session, name) for name in names[1:]]
                run.check()
        finally:
            run.stop()
    if first is None or last is None:
        raise RuntimeError("the fleet's sim did not answer its status")
    steps = last.steps - first.steps
    wall = last_wall - first_wall
    cpu = last_cpu - first_cpu
    late = _late([last, *last_all]) - _late([first, *first_all])
    return FleetResult(
        robots=count,
        mode=mode,
        steps_per_s=steps / wall,
        steps=steps,
        window_s=wall,
        cpu_us_per_robot_step=cpu / (steps * count) * 1e6 if steps else math.inf,
        sim_share=None if composed else ((last_sim_cpu - first_sim_cpu) / cpu if cpu > 0 else None),
        late_fraction=late / (steps * count) if steps else 1.0,
        cpu_cores=cpu / wall,
    )


def world_step_us(count: int, seconds: float) -> float:
    """µs of one world step of ``count`` robots that only the simulator's process can do, timed in
    place with no zenoh: reading every robot's wheel angles, setting its torques, applying them,
    ``stepSimulation`` and the contact check (:meth:`~sim_bridge.simulator.Simulator.step`), the
    same fleet file's robots driving the benchmark's circle with the motor's PD law. The motors'
    laws run too (the torques must be real ones) but are not counted: they are per robot, and what
    spreading the robots over processes could move off the sim's core.

    PyBullet holds the GIL and one world is one PyBullet client, so this part of every step stays
    on one core however the robots' services are spread: with ``cores`` cores a world step can take
    no less than it plus the rest divided by ``cores`` (:func:`spread_bound`)."""
    from services.config import Config
    from services.motor.core import MotorCore
    from sim_bridge.simulator import Placement, Simulator
    from sim_bridge.world import InitialPose, load_world

    config = Config()
    placements = [
        Placement(name, config.robot, InitialPose(x=0.0, y=ROBOT_SPACING_M * index, theta=0.0))
        for index, name in enumerate(robot_names(count))
    ]
    cores = [MotorCore(config.robot, config.motor) for _ in placements]
    for core in cores:
        core.set_target(loop.VX, loop.W)
    clock = time.perf_counter_ns
    world_ns = steps = 0
    with Simulator(config.robot, config.sim, load_world(WORLD), fleet=placements) as sim:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            for _ in range(loop.CLOCK_CHECK_STEPS // count):
                started = clock()
                angles = [robot.wheel_angles() for robot in sim.robots]
                read = clock()
                torques = [core.step(sim.time_ns, wheel) for core, wheel in zip(cores, angles)]
                laws = clock()
                for robot, torque in zip(sim.robots, torques):
                    robot.set_torques(torque)
                sim.step()
                world_ns += (read - started) + (clock() - laws)
                steps += 1
    return world_ns / steps / 1e3


def spread_bound(world_step_wall_us: float, serial_us: float, cores: int) -> float:
    """The most robot-steps/s spreading a fleet over ``cores`` cores could gain against one
    process whose world step takes ``world_step_wall_us``, if everything but ``serial_us`` (the
    sim's own work, :func:`world_step_us`) were shared perfectly and cost nothing to hand over
    (Amdahl's law): a bound, the real gain is below it."""
    rest = max(world_step_wall_us - serial_us, 0.0)
    return world_step_wall_us / (serial_us + rest / cores)


SPEED_TICKS = (100, 200, 500, 1_000, 2_000, 5_000, 10_000, 20_000, 50_000)
COST_TICKS = (20, 50, 100, 200, 500, 1_000, 2_000)
MODE_STYLES = {
    "separate": ("o-", "tab:blue"),
    "composed": ("s-", "tab:orange"),
    "composed_workers": ("^-", "tab:green"),
}


def plot(fleet: dict[str, Any], path: Path, title: str = "") -> None:
    """The ``fleet`` section of a results file as a PNG: steps/s against N (log-log, the real-time
    line at 1,000 steps/s) and CPU µs per robot-step against N, both modes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, (speed, cost) = plt.subplots(1, 2, figsize=(8.0, 3.4), dpi=80)
    for mode, (marker, color) in MODE_STYLES.items():
        sizes = [size for size in fleet["sizes"] if fleet.get(mode, {}).get(str(size), {}).get("steps_per_s")]
        if not sizes:
            continue
        entries = [fleet[mode][str(size)] for size in sizes]
        speed.plot(sizes, [entry["steps_per_s"] for entry in entries], marker, color=color, label=mode)
        cost.plot(sizes, [entry["cpu_us_per_robot_step"] for entry in entries], marker, color=color, label=mode)
    speed.axhline(1000.0, color="grey", linestyle="--", linewidth=1, label="real time (1 ms steps)")
    speed.set(xscale="log", yscale="log", xlabel="robots N", ylabel="world steps/s", title="steps/s")
    cost.set(xscale="log", yscale="log", xlabel="robots N", ylabel="µs", title="CPU per robot-step")
    for axes, ticks in ((speed, SPEED_TICKS), (cost, COST_TICKS)):
        axes.set_xticks(fleet["sizes"], [str(size) for size in fleet["sizes"]])
        low, high = axes.get_ylim()
        shown = [tick for tick in ticks if low <= tick <= high]
        axes.set_yticks(shown, [f"{tick:,}" for tick in shown])
        axes.minorticks_off()
        axes.grid(True, which="major", alpha=0.3)
        axes.legend(fontsize=8)
    if title:
        figure.suptitle(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m benchmarks.fleet RESULTS.json PLOT.png``: plot the ``fleet`` section of a results
    file (``python -m benchmarks --only fleet`` measures it)."""
    arguments = list(argv if argv is not None else sys.argv[1:])
    if len(arguments) != 2:
        print("usage: python -m benchmarks.fleet RESULTS.json PLOT.png", file=sys.stderr)
        return 2
    results = json.loads(Path(arguments[0]).read_text())
    machine = results.get("machine", {})
    title = (
        f"invent up --fleet --no-record, medians of {results.get('settings', {}).get('repeats', '?')} runs; "
        f"{machine.get('cores', '?')} cores, load average at start {machine.get('load_average_at_start')}"
    )
    plot(results["fleet"], Path(arguments[1]), title)
    print(f"wrote {arguments[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
