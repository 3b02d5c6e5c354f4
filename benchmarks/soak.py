"""The soak: the stack left running, watched (``make soak``; never part of ``make test``).

Two runs side by side for ``--duration`` seconds (default one hour), each with its own router:

- ``invent up --loop --no-record --mode realtime --scenario square``: the long-running stack, recording nothing;
- ``invent up --mode realtime --scenario <a circle lasting the soak>``: a recorded run, which ends
  by itself (outcome ``completed``) and writes its ``run.mcap`` and report.

Every ``--sample-every`` seconds it reads, for every process of both runs (each ``up`` and its
children), the resident memory (``VmRSS``) and the open files (``/proc/<pid>/fd``), and the
runs' health from the services' status replies (late and missing torques, internal errors), and
the recorded run's journals' size. At the end: each process's memory growth per hour after the
warm-up (a least-squares slope; for a service, of its C allocations in use too: ``status.memory``), its open files after the warm-up and at the end, the health,
the recording's size per simulated hour, and whether every process exited cleanly.
Writes ``benchmarks/results/soak.json``; figures in benchmarks/README.md, "Soak".
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from schemas.keys import Keys, Service
from schemas.status import SimStatus
from schemas.status_kinds import status_type
from services.recording.report import loop_health
from services.runtime.discovery import StatusReader
from services.runtime.session import free_port, open_session, session_config, stop_on_signals

RESULTS = Path(__file__).resolve().parent / "results" / "soak.json"
KEYS = Keys()
SERVICES = (Service.SIM, Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION, Service.DRIVE)
START_TIMEOUT_S = 60.0
STATUS_TIMEOUT_S = 2.0
END_TIMEOUT_S = 600.0
"""How long the recorded run may take past the soak to end by itself and write its recording."""


@dataclass
class Watched:
    """One ``invent up`` of the soak and what was sampled of it."""

    name: str
    process: subprocess.Popen[str]
    endpoint: str
    log: Path
    report_dir: Path | None = None
    session: zenoh.Session | None = None
    """The soak's own session in the run, opened once the run's router listens and kept: a
    session's first queries may reach no queryable (declarations propagate asynchronously)."""
    samples: list[dict[str, Any]] = field(default_factory=list)
    health: dict[str, Any] | None = None

    def processes(self) -> dict[str, int]:
        """``up`` and its children, by name (the child's ``invent`` command)."""
        found = {"up": self.process.pid}
        for pid in children_of(self.process.pid):
            found[command_name(pid)] = pid
        return found


def children_of(parent: int) -> list[int]:
    children = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == parent:
            children.append(int(entry))
    return children


def command_name(pid: int) -> str:
    try:
        words = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return str(pid)
    after = [word.decode() for word in words if word]
    for index, word in enumerate(after):
        if word in {"services.cli", "invent"} and index + 1 < len(after):
            return after[index + 1]
    return after[-1] if after else str(pid)


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def _open_files(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def loop_health_of(session: zenoh.Session) -> tuple[dict[str, Any] | None, dict[str, float]]:
    """The loop's health from its services' status replies (as ``invent up`` reports it), and each
    service's C allocations in use (MB, ``status.memory``: what its resident size would be without
    the allocator's high-water mark)."""
    reader = StatusReader(session, STATUS_TIMEOUT_S)
    statuses = {str(service): reader.get(KEYS.status(service), status_type(service)) for service in SERVICES}
    in_use = {
        name: status.memory.in_use_mb
        for name, status in statuses.items()
        if status is not None and status.memory is not None and isinstance(status.memory.in_use_mb, float)
    }
    sim = statuses.pop(str(Service.SIM))
    if not isinstance(sim, SimStatus):
        return None, in_use
    health = loop_health(sim, statuses)
    health["steps"] = sim.steps
    health["sim_time_s"] = sim.sim_time_s
    return health, in_use


def directory_mb(directory: Path) -> float:
    """What the files under ``directory`` hold, in MB; a file removed meanwhile (a recording that
    keeps the newest) counts nothing."""
    total = 0
    for path in directory.rglob("*"):
        try:
            total += path.stat().st_size if path.is_file() else 0
        except FileNotFoundError:
            continue
    return total / 1e6


def slope_per_hour(points: list[tuple[float, float]]) -> float:
    """Least-squares slope of (seconds, MB), in MB per hour."""
    if len(points) < 2:
        return 0.0
    mean_t = sum(t for t, _ in points) / len(points)
    mean_v = sum(v for _, v in points) / len(points)
    spread = sum((t - mean_t) ** 2 for t, _ in points)
    if spread == 0:
        return 0.0
    return sum((t - mean_t) * (v - mean_v) for t, v in points) / spread * 3600


def _start(name: str, work: Path, *flags: str, report_dir: Path | None = None) -> Watched:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = work / f"{name}.log"
    with log.open("w") as output:
        process = subprocess.Popen(
            [sys.executable, "-m", "services.cli", "up", *flags, "--listen", endpoint, "--log-level", "warning"],
            stdout=output,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
    return Watched(name, process, endpoint, log, report_dir)


def _join(run: Watched, stack: ExitStack) -> None:
    """The soak's session in ``run``, once its services are alive."""
    session = stack.enter_context(open_session(session_config(connect=[run.endpoint])))
    deadline = time.monotonic() + START_TIMEOUT_S
    alive: set[str] = set()
    subscriber = session.liveliness().declare_subscriber(
        KEYS.alive(Service.SIM), lambda sample: alive.add(str(sample.key_expr)), history=True
    )
    while not alive:
        if time.monotonic() > deadline or run.process.poll() is not None:
            raise RuntimeError(f"the {run.name} run did not start: see {run.log}")
        time.sleep(0.1)
    subscriber.undeclare()
    run.session = session


def _sample(run: Watched, elapsed: float) -> None:
    sample: dict[str, Any] = {"t_s": elapsed, "processes": {}}
    for name, pid in run.processes().items():
        sample["processes"][name] = {"rss_mb": rss_mb(pid), "open_files": _open_files(pid)}
    if run.session is not None:
        health, in_use = loop_health_of(run.session)
        run.health = health or run.health
        sample["allocated_mb"] = in_use
    sample["health"] = run.health
    if run.report_dir is not None and (run.report_dir / "journals").exists():
        sample["journals_mb"] = directory_mb(run.report_dir / "journals")
    run.samples.append(sample)


def _summary(run: Watched, warm_up_s: float) -> dict[str, Any]:
    processes: dict[str, Any] = {}
    names = {name for sample in run.samples for name in sample["processes"]}
    for name in sorted(names):
        series = [
            (sample["t_s"], sample["processes"][name])
            for sample in run.samples
            if name in sample["processes"] and sample["processes"][name]["rss_mb"] is not None
        ]
        after = [(t, values) for t, values in series if t >= warm_up_s]
        if not after:
            continue
        processes[name] = {
            "rss_mb_after_warm_up": after[0][1]["rss_mb"],
            "rss_mb_at_end": after[-1][1]["rss_mb"],
            "rss_growth_mb_per_hour": slope_per_hour([(t, values["rss_mb"]) for t, values in after]),
            "open_files_after_warm_up": after[0][1]["open_files"],
            "open_files_at_end": after[-1][1]["open_files"],
        }
    for name, entry in processes.items():
        allocated = [
            (sample["t_s"], sample["allocated_mb"][name])
            for sample in run.samples
            if sample["t_s"] >= warm_up_s and name in sample.get("allocated_mb", {})
        ]
        if allocated:
            entry["allocated_mb_at_end"] = allocated[-1][1]
            entry["allocated_growth_mb_per_hour"] = slope_per_hour(allocated)
    health = run.health or {}
    internal = {name: counts["internal_errors"] for name, counts in health.get("services", {}).items()}
    return {
        "processes": processes,
        "max_rss_growth_mb_per_hour": max((p["rss_growth_mb_per_hour"] for p in processes.values()), default=None),
        "steps": health.get("steps"),
        "sim_time_s": health.get("sim_time_s"),
        "torques": health.get("torques"),
        "internal_errors": internal,
        "exit_code": run.process.returncode,
    }


def _stop(run: Watched, timeout: float) -> None:
    if run.process.poll() is None:
        run.process.send_signal(signal.SIGINT)
    try:
        run.process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(run.process.pid, signal.SIGKILL)
        run.process.wait()


def soak(duration_s: float, sample_every_s: float, warm_up_s: float, work: Path) -> dict[str, Any]:
    scenario = work / "long_circle.toml"
    scenario.write_text(
        f'name = "soak circle"\n[[segments]]\ntype = "constant"\nvx = 0.25\nw = 0.5\nduration = {duration_s}\n'
    )
    looping = _start("loop", work, "--loop", "--no-record", "--mode", "realtime", "--scenario", "square")
    recorded = _start(
        "recorded",
        work,
        "--mode",
        "realtime",
        "--scenario",
        str(scenario),
        "--report",
        str(work / "recorded"),
        report_dir=work / "recorded",
    )
    runs = (looping, recorded)
    stop = stop_on_signals()  # Ctrl-C ends the soak early, with its figures so far
    started = time.monotonic()
    stack = ExitStack()
    try:
        for run in runs:
            _join(run, stack)
        next_sample = started
        while (
            (elapsed := time.monotonic() - started) < duration_s
            and recorded.process.poll() is None
            and not stop.is_set()
        ):
            if looping.process.poll() is not None:
                raise RuntimeError(f"the --loop run exited early ({looping.process.returncode})")
            if time.monotonic() >= next_sample:
                for run in runs:
                    _sample(run, elapsed)
                print(
                    f"soak {elapsed:6.0f}/{duration_s:.0f} s | "
                    + " | ".join(
                        f"{run.name}: sim {((run.health or {}).get('sim_time_s') or 0):.0f} s, "
                        f"rss {sum((p['rss_mb'] or 0) for p in run.samples[-1]['processes'].values()):.0f} MB"
                        for run in runs
                    ),
                    flush=True,
                )
                next_sample += sample_every_s
            time.sleep(0.5)
        for run in runs:
            _sample(run, time.monotonic() - started)
        stack.close()
        _stop(looping, 60)
        if stop.is_set():
            _stop(recorded, END_TIMEOUT_S)
        recorded.process.wait(timeout=END_TIMEOUT_S)
    finally:
        stack.close()
        for run in runs:
            if run.process.poll() is None:
                _stop(run, 60)
    recording = work / "recorded" / "run.mcap"
    report_path = work / "recorded" / "report.json"
    report = json.loads(report_path.read_text()) if report_path.exists() else {}
    sim_time_s = report.get("sim_time_s") or 0.0
    size_mb = recording.stat().st_size / 1e6 if recording.exists() else None
    leftovers = [pid for run in runs for pid in children_of(run.process.pid)]
    return {
        "duration_s": duration_s,
        "sample_every_s": sample_every_s,
        "warm_up_s": warm_up_s,
        "loop": _summary(looping, warm_up_s),
        "recorded": {
            **_summary(recorded, warm_up_s),
            "outcome": report.get("outcome"),
            "recording_mb": size_mb,
            "recording_mb_per_simulated_hour": None if not (size_mb and sim_time_s) else size_mb / sim_time_s * 3600,
            "journals_mb_peak": max((s.get("journals_mb", 0.0) for s in recorded.samples), default=0.0),
            "report_health": report.get("health"),
        },
        "processes_left": leftovers,
        "loop_end": looping.log.read_text().splitlines()[-8:],
        "recorded_end": recorded.log.read_text().splitlines()[-14:],
        "samples": {run.name: run.samples for run in runs},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="seconds (default 3600)")
    parser.add_argument("--sample-every", type=float, default=10.0, help="seconds between samples (default 10)")
    parser.add_argument("--warm-up", type=float, default=60.0, help="seconds before memory is compared (default 60)")
    parser.add_argument("--output", type=Path, default=RESULTS, help=f"(default {RESULTS})")
    args = parser.parse_args(argv)
    if args.warm_up >= args.duration:
        parser.error("--warm-up must be shorter than --duration")
    with tempfile.TemporaryDirectory(prefix="invent-soak-") as work:
        result = soak(args.duration, args.sample_every, args.warm_up, Path(work))
    print(
        "\n".join(
            ["--- the --loop run's end:", *result["loop_end"], "--- the recorded run's end:", *result["recorded_end"]]
        )
    )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    brief = {key: value for key, value in result.items() if key != "samples"}
    print(json.dumps(brief, indent=2))
    internal = sum(sum(run["internal_errors"].values()) for run in (result["loop"], result["recorded"]))
    healthy = internal == 0 and not result["processes_left"] and result["recorded"]["exit_code"] == 0
    return 0 if healthy else 1


if __name__ == "__main__":
    sys.exit(main())
