"""The closed loop measured: as separate processes, through ``invent up`` (also ``--composed``),
and its in-process limit.

Each loop runs a constant-velocity scenario (a circle, long enough never to end). The benchmark
joins its router with a session of its own, waits until the drive is alive and a warm-up has
passed, then reads the sim's status at the start and at the end of a measuring window: steps
per second = steps stepped / wall seconds between the two replies, so start-up and shut-down
are left out. The two replies' latency histograms, subtracted, give the torque latency (wheel
angles published -> matching torque received) of exactly the window's steps; their counters
give the late and missing fractions. The processes are then stopped with SIGINT, as Ctrl-C would.

The in-process limit steps the same robot (:class:`~sim_bridge.simulator.Simulator`) with the
same PD law (:class:`~services.motor.core.MotorCore`) in one loop with no zenoh: scan and sample
the IMU when due, read the wheel angles, compute the torques, apply them, step.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from schemas.keys import Keys, Service, ServiceName
from schemas.messages import Time
from schemas.status import SimStatus, StatusT, TorqueLatencyStatus
from services import interfaces
from services.config import Config
from services.motor.core import MotorCore
from services.runtime.discovery import StatusReader
from services.runtime.session import free_port, open_session, session_config
from sim_bridge.latency import percentiles

REPO = Path(__file__).resolve().parent.parent
VX, W = 0.3, 0.3
"""The benchmark's constant command: a circle of 1 m radius, so any duration stays on the floor."""
SCENARIO_SECONDS = 100_000.0
"""Simulated seconds of the scenario: the run is always stopped before it ends."""
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 30.0
STATUS_TIMEOUT_S = 2.0
POLL_S = 0.05
CLOCK_CHECK_STEPS = 500
"""In-process limit: steps between two looks at the clock."""
KEYS = Keys()
COMPOSED_FLAG = "--composed"
NO_RECORD_FLAG = "--no-record"
ROS2_FLAG = "--ros2"
NO_INTRA_PROCESS_FLAG = "--no-intra-process"
RT_FLAG = "--rt"
NO_SENSORS_FLAGS = ("--set", "lidar.enabled=false", "--set", "imu.enabled=false")
"""The robot without its lidar and IMU: the loop as it was before the sensors."""


@dataclass(frozen=True)
class LoopResult:
    steps_per_s: float
    sim_seconds_per_s: float
    latency_us: dict[str, float | None]
    late_fraction: float
    """Late steps / steps over the window (lockstep: timed out; realtime: stepped before their torque)."""
    missing_fraction: float
    steps: int
    window_s: float
    cpu_us_per_step: float
    """CPU time (user + system) of every process of the loop over the window, per step: what the
    machine's load does not change, where ``steps_per_s`` moves with it."""
    gc: dict[str, Any] | None = None
    """The sim's garbage collections over the window (``status.rt``): per generation, and the longest pause."""

    def as_dict(self) -> dict[str, Any]:
        return {
            "steps_per_s": self.steps_per_s,
            "gc": self.gc,
            "cpu_us_per_step": self.cpu_us_per_step,
            "real_time_factor": self.sim_seconds_per_s,
            "latency_us": self.latency_us,
            "late_fraction": self.late_fraction,
            "missing_fraction": self.missing_fraction,
            "steps": self.steps,
            "window_s": self.window_s,
        }


def inprocess_steps_per_s(seconds: float, sensors: bool = True) -> float:
    """Steps per second of Simulator + MotorCore in one loop, no zenoh, for ``seconds`` of wall time;
    with ``sensors``, the robot's lidar scans and IMU samples at their rates too, as the sim does."""
    from sim_bridge.simulator import Simulator
    from sim_bridge.world import load_world

    config = Config()
    core = MotorCore(config.robot, config.motor)
    core.set_target(VX, W)
    lidar, imu = (config.lidar, config.imu) if sensors else (None, None)
    with Simulator(config.robot, config.sim, load_world(None), lidar=lidar, imu=imu) as sim:
        robot = sim.robots[0]
        scans, samples = robot.lidar, robot.imu
        started = time.perf_counter()
        deadline = started + seconds
        while True:
            for _ in range(CLOCK_CHECK_STEPS):
                now_ns = sim.time_ns
                if scans is not None and scans.schedule.due(now_ns):
                    robot.scan(Time.from_nanoseconds(now_ns))
                if samples is not None and samples.schedule.due(now_ns):
                    robot.imu_sample(Time.from_nanoseconds(now_ns))
                sim.set_torques(core.step(now_ns, sim.wheel_angles()))
                sim.step()
            now = time.perf_counter()
            if now >= deadline:
                return sim.step_index / (now - started)


def scenario_file(directory: Path) -> Path:
    path = directory / "bench_circle.toml"
    path.write_text(
        f'name = "bench circle"\n\n[[segments]]\ntype = "constant"\nvx = {VX}\nw = {W}\nduration = {SCENARIO_SECONDS}\n'
    )
    return path


def service_status(
    session: zenoh.Session, service: ServiceName, status_type: type[StatusT], keys: Keys = KEYS
) -> StatusT | None:
    """``service``'s status, or None when it does not answer or its reply does not decode as ``status_type``."""
    return StatusReader(session, STATUS_TIMEOUT_S).get(keys.status(service), status_type)


def sim_status(session: zenoh.Session, keys: Keys = KEYS) -> SimStatus | None:
    return service_status(session, Service.SIM, SimStatus, keys)


def _state(status: SimStatus | None) -> str | None:
    return None if status is None else status.state


def _alive(session: zenoh.Session, service: Service) -> bool:
    return any(reply.ok is not None for reply in session.liveliness().get(KEYS.alive(service), timeout=1.0))


class UpRun:
    """One ``invent up`` in the background, its output in a log file."""

    def __init__(self, flags: Sequence[str], directory: Path) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.log_path = directory / f"up-{time.monotonic_ns()}.log"
        argv = [
            sys.executable, "-m", "services.cli", "up",
            "--scenario", str(scenario_file(directory)),
            "--listen", self.endpoint,
            *([] if NO_RECORD_FLAG in flags else ["--report", str(directory / "report")]),
            "--log-level", "warning",
            *flags,
        ]  # fmt: skip
        self._log = self.log_path.open("w")
        self.process = subprocess.Popen(argv, cwd=REPO, stdout=self._log, stderr=subprocess.STDOUT)

    @property
    def pids(self) -> list[int]:
        """``up``: its processes are its descendants."""
        return [self.process.pid]

    def output(self, lines: int = 30) -> str:
        return "\n".join(self.log_path.read_text().splitlines()[-lines:])

    def check(self) -> None:
        if self.process.poll() is not None:
            raise RuntimeError(f"invent up exited with {self.process.returncode}:\n{self.output()}")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()


class ServicesRun:
    """The loop's services as separate processes started here, as ``invent up`` starts them
    (router, motor, odometry, localization, then the drive, then the sim waiting for them),
    without ``up``'s run recorder: the loop itself, nothing listening beside it."""

    def __init__(
        self,
        flags: Sequence[str],
        directory: Path,
        env: Mapping[str, str] | None = None,
        control_path_flags: Sequence[str] = (),
    ) -> None:
        """``control_path_flags``: for the router, the motor and the sim (as ``invent up --rt`` gives them ``--rt``)."""
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.log_path = directory / f"services-{time.monotonic_ns()}.log"
        self._log = self.log_path.open("w")
        self._directory = directory
        self._sim_flags = list(flags)
        self._control = list(control_path_flags)
        self._env = {**os.environ, **(env or {})}
        self.processes: dict[str, subprocess.Popen[bytes]] = {}
        self._start("router", ["router", "--listen", self.endpoint, *self._control])

    def _start(self, name: str, argv: Sequence[str]) -> None:
        self.processes[name] = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *argv, "--log-level", "warning"],
            cwd=REPO,
            env=self._env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )

    def start_loop(self, session: zenoh.Session) -> None:
        connect = ["--connect", self.endpoint]
        for service in (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION):
            self._start(str(service), [str(service), *connect, *(self._control if service == Service.MOTOR else [])])
        for service in (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION):
            _wait(lambda service=service: _alive(session, service), f"the {service}", self)
        self._start("drive", ["drive", *connect, "--scenario", str(scenario_file(self._directory))])
        _wait(lambda: _alive(session, Service.DRIVE), "the drive", self)
        # the motor and the loop's lockstep participants, as the services declare them (invent up's waits)
        participants = interfaces.participants(Keys(), Config())
        wait_for = [str(Service.MOTOR), *(str(one.service) for one in participants)]
        self._start("sim", ["sim", *connect, *self._sim_flags, *self._control, "--wait-for", *wait_for])

    @property
    def pids(self) -> list[int]:
        return [process.pid for process in self.processes.values()]

    def output(self, lines: int = 30) -> str:
        return "\n".join(self.log_path.read_text().splitlines()[-lines:])

    def check(self) -> None:
        for name, process in self.processes.items():
            if process.poll() is not None:
                raise RuntimeError(f"{name} exited with {process.returncode}:\n{self.output()}")

    def stop(self) -> None:
        for process in reversed(self.processes.values()):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in reversed(self.processes.values()):
            try:
                process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self._log.close()


def _wait(predicate, what: str, run: UpRun | ServicesRun) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not predicate():
        run.check()
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}:\n{run.output()}")
        time.sleep(POLL_S)


def measure_up(flags: Sequence[str], warmup_s: float, window_s: float) -> LoopResult:
    """Run ``invent up`` with ``flags`` and measure the sim over ``window_s`` after ``warmup_s``."""
    with tempfile.TemporaryDirectory(prefix="invent-bench-") as folder:
        run = UpRun(flags, Path(folder))
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                return _measure(session, run, warmup_s, window_s)
        finally:
            run.stop()


def measure_services(
    sim_flags: Sequence[str],
    warmup_s: float,
    window_s: float,
    env: Mapping[str, str] | None = None,
    control_path_flags: Sequence[str] = (),
) -> LoopResult:
    """Start the services as separate processes (:class:`ServicesRun`, with ``env`` added to
    their environment, ``control_path_flags`` to the router's, the motor's and the sim's flags) and
    measure like :func:`measure_up`."""
    with tempfile.TemporaryDirectory(prefix="invent-bench-") as folder:
        run = ServicesRun(sim_flags, Path(folder), env, control_path_flags)
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                run.start_loop(session)
                return _measure(session, run, warmup_s, window_s)
        finally:
            run.stop()


def window_latency(first: TorqueLatencyStatus, last: TorqueLatencyStatus) -> dict[str, float | None]:
    """p50, p99 and max (to the sim's bin width) of the torque latencies counted between two
    ``torque_latency`` status entries: the difference of their histograms."""
    counts = {index: count for index, count in last.histogram}
    for index, count in first.histogram:
        counts[index] -= count
    window = {index: count for index, count in counts.items() if count > 0}
    p50, p99, top = percentiles(window, (0.50, 0.99, 1.0))
    return {"p50": p50, "p99": p99, "max": top}


def cpu_seconds(roots: Sequence[int]) -> float:
    """User + system CPU seconds of the processes ``roots`` and all their descendants, those
    already reaped included (in their parent's children's times), from /proc (Linux)."""
    tree: dict[int, list[int]] = {}
    times: dict[int, float] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # it ended meanwhile
            continue
        pid = int(entry)
        tree.setdefault(int(fields[1]), []).append(pid)
        times[pid] = sum(int(field) for field in fields[11:15]) / os.sysconf("SC_CLK_TCK")
    total, pending = 0.0, list(roots)
    while pending:
        pid = pending.pop()
        total += times.get(pid, 0.0)
        pending.extend(tree.get(pid, []))
    return total


def wait_until_running(session: zenoh.Session, run: UpRun | ServicesRun) -> None:
    """Until the drive is alive and the sim steps (or ``run`` failed: RuntimeError)."""
    _wait(lambda: _alive(session, Service.DRIVE), "the drive", run)
    _wait(lambda: _state(sim_status(session)) == "running", "the sim running", run)


def _measure(session: zenoh.Session, run: UpRun | ServicesRun, warmup_s: float, window_s: float) -> LoopResult:
    wait_until_running(session, run)
    time.sleep(warmup_s)
    first, first_wall, first_cpu = sim_status(session), time.monotonic(), cpu_seconds(run.pids)
    time.sleep(window_s)
    last, last_wall, last_cpu = sim_status(session), time.monotonic(), cpu_seconds(run.pids)
    run.check()
    if first is None or last is None:
        raise RuntimeError("the sim did not answer its status")
    steps = last.steps - first.steps
    wall = last_wall - first_wall
    late = (
        last.counters.long_waits - first.counters.long_waits
        if last.mode == "lockstep"
        else last.counters.realtime_late_steps - first.counters.realtime_late_steps
    )
    missing = last.counters.missing_torques - first.counters.missing_torques
    first_rt, last_rt = first.rt, last.rt
    gc = (
        {
            "policy": last_rt.gc,
            "collections": [b - a for a, b in zip(first_rt.gc_collections, last_rt.gc_collections, strict=True)],
            "pause_us_per_step": (last_rt.gc_total_pause_us - first_rt.gc_total_pause_us) / steps if steps else None,
            "max_pause_us_since_start": last_rt.gc_max_pause_us,
            "sched": f"{last_rt.policy} {last_rt.priority}",
            "cpus": last_rt.cpus,
        }
        if last_rt is not None and first_rt is not None
        else None
    )
    return LoopResult(
        gc=gc,
        steps_per_s=steps / wall,
        sim_seconds_per_s=(last.sim_time_s - first.sim_time_s) / wall,
        latency_us=window_latency(first.torque_latency, last.torque_latency),
        late_fraction=late / steps if steps else 1.0,
        missing_fraction=missing / steps if steps else 1.0,
        steps=steps,
        window_s=wall,
        cpu_us_per_step=(last_cpu - first_cpu) / steps * 1e6 if steps else math.inf,
    )
