"""A simulated day left alone (``make soak-day``; never part of ``make test``): 24 hours of errands
through the three_rooms world (sim_bridge/worlds/three_rooms.toml: three rooms, two doors) in one
composed lockstep run on the kinematic engine, with the lidar, the collision monitor, the planner and
amcl on the world's map, and faults injected on a schedule.

The stack: a router of its own (``invent router``), ``invent up --composed --connect`` on it with
``--goal-file`` (the day's errands, written here: one every ``--period`` seconds of simulation time to
a place of :data:`PLACES` drawn with a fixed seed), ``--with`` a fix ledger
(examples/services/fix_ledger.py: a lockstep participant, a process of its own beside the composed loop)
and ``--restart on-failure``. The faults, at fixed simulation times (:data:`FAULTS`):

- ``service``: the service beside the loop killed with SIGKILL; the restart policy starts it again. Measured: the
  wall seconds until its liveliness token is back.
- ``router``: the router killed with SIGKILL and started again a second later, as a supervisor
  would. Measured: the wall seconds until a status query through it is answered again (the soak's
  session is a client: all it sends goes through the router).
- ``hostile``: a burst of hostile payloads (tests/hostile_payloads.py, as ``make fuzz`` sends them) on
  ``drive/goal/send``, ``drive/goal/cancel`` and ``sim/scan`` from outside, through the router: each
  refused by its reply and counted by every service that takes the key. The payloads are drawn
  before the day starts: drawing them is the soak's work, not the stack's.

Every ``--sample-every`` wall seconds it takes each process's resident memory, the report
directory's size and the simulation time. At the end (the last errand done, the run ends by itself):
the report's goals, restarts, internal errors, late or missing torques and bad inputs; each process's
memory growth per simulated hour after the first (and after its last start), also with the step a
burst of hostile input sets left out (zenoh's buffers grow once, to the burst's high water, and stay:
``python -m benchmarks.burst_memory`` measures it on a router alone); the recording
against ``record.max_size``; the wall time. Exits 1 unless every errand completed, every fault was
survived, no internal error, memory flat (under :data:`FLAT_MB_PER_HOUR` past the high water) and
the recording within its budget. Writes ``benchmarks/results/soak_day.json``; benchmarks/README.md
quotes it.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from benchmarks.day_memory import FLAT_MB_PER_HOUR, growth, past_high_water, since, steps_at_bursts
from benchmarks.hostile_bursts import Burst, draw_bursts
from benchmarks.soak import directory_mb, rss_mb
from schemas.codec import decode
from schemas.keys import Keys, Service, ServiceName
from schemas.messages import ScenarioOutcome
from schemas.status import ServiceStatus
from schemas.status_kinds import status_type
from services.config import load_config
from services.runtime.discovery import StatusReader
from services.runtime.session import ROUTER_LISTENING, free_port, open_session, session_config

RESULTS = Path(__file__).resolve().parent / "results" / "soak_day.json"
KEYS = Keys()
BESIDE = "examples/services/fix_ledger.py:FixLedger"
BESIDE_NAME = "fixes"
PLACES = ((0.0, 0.0), (0.5, 0.5), (0.0, -1.0), (4.0, 1.0), (4.0, -1.0), (8.0, 0.0), (8.5, 1.0))
"""Where errands go: each room's middle and corners clear of the walls (the three_rooms tour's)."""
ERRAND_LIMIT_MARGIN_S = 10.0
"""An errand's time limit: the period less this (the longest leg takes about 45 s)."""
FAULTS = (
    (2.5, "hostile"),
    (3.0, "service"),
    (6.0, "router"),
    (8.5, "hostile"),
    (9.0, "service"),
    (12.0, "router"),
    (14.5, "hostile"),
    (15.0, "service"),
    (18.0, "router"),
    (20.5, "hostile"),
    (21.0, "service"),
)
"""(hour of a 24-hour day, fault): each kind three or four times, spread over the day; a shorter run
(``--sim-hours``) has them at the same fractions of its length."""
PROGRESS = re.compile(r"sim +([\d.]+) s \|")
STARTED = re.compile(rf"started {BESIDE_NAME} \(pid (\d+)\)")
GOAL_ENDED = re.compile(r"invent\.drive: goal '([^']+)' (\w+) after [\d.]+ s")
"""The drive's own line for each goal's end (INFO when completed, WARNING otherwise)."""
BACK_TIMEOUT_S = 120.0
STATUS_TIMEOUT_S = 5.0
END_TIMEOUT_S = 3600.0
"""How long the run may take, once its errands are done, to write its recording and report."""
SCAN_CONSUMERS = (Service.MOTOR, Service.DRIVE, Service.LOCALIZATION)
"""Who takes ``sim/scan`` here: the collision monitor, the costmap, amcl."""


def errands(sim_hours: float, period_s: float, seed: int) -> str:
    """The day's goal file: one errand every ``period_s`` to a place other than the last."""
    draw = random.Random(seed)
    here = PLACES[0]
    lines = ['name = "a_day_of_errands"']
    for index in range(int(sim_hours * 3600 / period_s)):
        there = draw.choice([place for place in PLACES if place != here])
        lines += ["", "[[goals]]", f"at = {index * period_s:.1f}", f"x = {there[0]}", f"y = {there[1]}"]
        lines += [f"time_limit = {period_s - ERRAND_LIMIT_MARGIN_S:.1f}", f'id = "errand_{index}"']
        here = there
    return "\n".join(lines) + "\n"


def wait_for(predicate: Callable[[], Any], timeout_s: float) -> float | None:
    """Wall seconds until ``predicate()`` is true, or None past ``timeout_s``."""
    begun = time.monotonic()
    while time.monotonic() - begun < timeout_s:
        if predicate():
            return round(time.monotonic() - begun, 2)
        time.sleep(0.05)
    return None


@dataclass
class Day:
    """The running day: its processes, what up printed, the samples and the faults so far."""

    endpoint: str
    report_dir: Path
    router: subprocess.Popen[str]
    bursts: list[Burst]
    """The hostile bursts still to send, drawn before the day started."""
    up: subprocess.Popen[str] | None = None
    sim_s: float = 0.0
    beside_pids: list[int] = field(default_factory=list)
    tail: list[str] = field(default_factory=list)
    samples: list[dict[str, Any]] = field(default_factory=list)
    faults: list[dict[str, Any]] = field(default_factory=list)
    router_starts: int = 1
    outcomes: dict[str, list[str]] = field(default_factory=dict)
    """Each goal's end as the drive logged it, by outcome: the ids. Over the whole run, which a
    recording that keeps the newest no longer holds, and whatever the router does."""
    outcomes_through_the_router: dict[str, list[str]] = field(default_factory=dict)
    """The same from ``drive/outcome``, subscribed through the router: an end published while the
    router was down (or up not yet connected to its new one) is not among them."""
    loop_ended: bool = False
    """Up has begun writing its recording: the loop is over, and its memory no longer the loop's."""

    def read_up(self) -> None:
        """Up's lines, on a thread of their own: the simulation time and the pids of the service beside."""
        assert self.up is not None and self.up.stdout is not None
        for line in self.up.stdout:
            self.read_line(line)

    def read_line(self, line: str) -> None:
        """One line of up's: each pattern looked for on its own, as lines of up's stdout and of its
        services' stderr can be glued on one (a whole day read 719 of 720 goals' ends so; the drive's own
        counters, in its status, said 720)."""
        if "from what the services published" in line:
            self.loop_ended = True
        if (progress := PROGRESS.search(line)) is not None:
            self.sim_s = float(progress.group(1))
        self.beside_pids += [int(started.group(1)) for started in STARTED.finditer(line)]
        for ended in GOAL_ENDED.finditer(line):
            self.outcomes.setdefault(ended.group(2), []).append(ended.group(1))
        self.tail.append(line)
        del self.tail[:-200]
        if "WARNING" in line or "ERROR" in line or "restart" in line:
            sys.stdout.write(line)
            sys.stdout.flush()

    def on_outcome(self, sample: zenoh.Sample) -> None:
        """A zenoh callback: only notes the end (nothing of zenoh's is called from here)."""
        outcome = decode(ScenarioOutcome, sample.payload.to_bytes())
        self.outcomes_through_the_router.setdefault(outcome.outcome, []).append(outcome.goal_id)

    def sample(self) -> None:
        if self.loop_ended:
            return
        processes = {"up": self.up.pid if self.up else None, "router": self.router.pid}
        processes[BESIDE_NAME] = self.beside_pids[-1] if self.beside_pids else None
        self.samples.append(
            {
                "wall_s": round(time.monotonic(), 1),
                "sim_h": round(self.sim_s / 3600, 4),
                "rss_mb": {name: rss_mb(pid) if pid else None for name, pid in processes.items()},
                "report_dir_mb": round(directory_mb(self.report_dir), 1),
            }
        )


def start_router(endpoint: str) -> subprocess.Popen[str]:
    router = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "router", "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert router.stdout is not None
    for line in router.stdout:
        if ROUTER_LISTENING in line:
            threading.Thread(target=lambda: [None for _ in router.stdout or ()], daemon=True).start()
            return router
    raise RuntimeError(f"the router did not start: exit {router.wait()}")


def status(session: zenoh.Session, service: ServiceName, timeout_s: float = STATUS_TIMEOUT_S) -> ServiceStatus | None:
    return StatusReader(session, timeout_s).get(KEYS.status(service), status_type(service))


def bad_input_counts(session: zenoh.Session, key: str, services: tuple[Service, ...]) -> list[int]:
    counts = []
    for service in services:
        answered = status(session, service)
        entry = None if answered is None else answered.bad_input.by_key.get(key)
        counts.append(0 if entry is None else entry.count)
    return counts


def kill_the_service_beside(day: Day, session: zenoh.Session) -> dict[str, Any]:
    before = len(day.beside_pids)
    victim = day.beside_pids[-1]
    subprocess.run(["kill", "-KILL", str(victim)], check=False)
    back_s = wait_for(
        lambda: (
            len(day.beside_pids) > before
            and any(True for _ in session.liveliness().get(KEYS.alive(BESIDE_NAME), timeout=1.0))
        ),
        BACK_TIMEOUT_S,
    )
    return {"killed_pid": victim, "back_within_s": back_s, "survived": back_s is not None}


def kill_the_router(day: Day, session: zenoh.Session) -> dict[str, Any]:
    day.router.kill()
    day.router.wait()
    time.sleep(1.0)
    day.router = start_router(day.endpoint)
    day.router_starts += 1
    back_s = wait_for(lambda: status(session, Service.DRIVE, timeout_s=0.5) is not None, BACK_TIMEOUT_S)
    return {"back_within_s": back_s, "survived": back_s is not None}


def hostile_burst(session: zenoh.Session, burst: Burst) -> dict[str, Any]:
    """Each payload refused by its reply (the queryables) and counted by each service that takes it."""
    result: dict[str, Any] = {}
    for name, key, payloads, refused in (
        ("drive/goal/send", KEYS.drive_goal_send, burst.goals, lambda r: not json.loads(r)["accepted"]),
        ("drive/goal/cancel", KEYS.drive_goal_cancel, burst.cancels, lambda r: json.loads(r)["canceling"] == []),
    ):
        refusals = 0
        for payload in payloads:
            replies = [reply for reply in session.get(key, payload=payload, timeout=STATUS_TIMEOUT_S)]
            refusals += len(replies) == 1 and (replies[0].ok is None or refused(replies[0].ok.payload.to_bytes()))
        result[name] = {"sent": len(payloads), "refused": refusals}
    payloads = burst.scans
    before = bad_input_counts(session, KEYS.sim_scan, SCAN_CONSUMERS)
    for payload in payloads:
        session.put(KEYS.sim_scan, payload)
    expected = [count + len(payloads) for count in before]
    counted_s = wait_for(lambda: bad_input_counts(session, KEYS.sim_scan, SCAN_CONSUMERS) == expected, 30.0)
    result["sim/scan"] = {"sent": len(payloads), "counted_by_each": counted_s is not None}
    result["survived"] = all(
        entry["refused"] == entry["sent"] for name, entry in result.items() if name.startswith("drive/")
    ) and bool(result["sim/scan"]["counted_by_each"])
    return result


FAULT_ACTIONS: dict[str, Callable[[Day, zenoh.Session], dict[str, Any]]] = {
    "service": kill_the_service_beside,
    "router": kill_the_router,
    "hostile": lambda day, session: hostile_burst(session, day.bursts.pop(0)),
}


def soak_day(sim_hours: float, period_s: float, sample_every_s: float, work: Path) -> dict[str, Any]:
    config = load_config(None, {"record.keep": "newest"})
    warm_up_h = min(1.0, sim_hours / 4)  # memory growth counts after the first hour (a short run's first quarter)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    report_dir = work / "run"
    goal_file = work / "day.toml"
    goal_file.write_text(errands(sim_hours, period_s, seed=2026))
    map_file = work / "three_rooms.yaml"
    made = subprocess.run(
        [sys.executable, "-m", "services.cli", "map", "--world", "three_rooms", "-o", str(map_file)],
        capture_output=True,
        text=True,
        check=False,
    )
    if made.returncode != 0:
        raise RuntimeError(f"invent map: {made.stderr}")
    command = ["up", "--composed", "--connect", endpoint, "--engine", "kinematic", "--goal-file", str(goal_file)]
    command += ["--set", "sim.world=three_rooms", "--map", str(map_file), "--set", "localization.mode=amcl"]
    command += ["--with", BESIDE, "--restart", "on-failure", "--report", str(report_dir)]
    bursts = draw_bursts(sum(kind == "hostile" for _, kind in FAULTS))
    started = time.monotonic()
    day = Day(endpoint, report_dir, start_router(endpoint), bursts)
    day.up = subprocess.Popen(
        [sys.executable, "-m", "services.cli", *command], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    reader = threading.Thread(target=day.read_up, daemon=True)
    reader.start()
    try:
        run_the_day(day, sim_hours, period_s, sample_every_s, started)
    finally:
        for process in (day.up, day.router):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
    day.up.wait(timeout=END_TIMEOUT_S)
    reader.join(timeout=10.0)
    wall_s = time.monotonic() - started
    day.router.wait(timeout=30)
    errands_sent = {"period_s": period_s, "in_goal_file": int(sim_hours * 3600 / period_s)}
    return summary(day, command, wall_s, errands_sent, config.record.max_size or 0.0, warm_up_h)


def run_the_day(day: Day, sim_hours: float, period_s: float, sample_every_s: float, started: float) -> None:
    """Sample, and inject the faults at their times, until ``up`` ends by itself."""
    assert day.up is not None
    pending = list(FAULTS)
    next_sample = 0.0
    # a client: everything it sends and takes goes through the router (a peer would also reach the loop
    # directly, and a router killed would cut it from nothing)
    with open_session(session_config(connect=[day.endpoint], mode="client")) as session:
        session.declare_subscriber(KEYS.drive_outcome, day.on_outcome)
        while day.up.poll() is None:
            if time.monotonic() >= next_sample:
                next_sample = time.monotonic() + sample_every_s
                day.sample()
                print(
                    f"soak-day: sim {day.sim_s / 3600:6.2f} h, wall {(time.monotonic() - started) / 60:5.1f} min, "
                    f"rss {day.samples[-1]['rss_mb']}, report dir {day.samples[-1]['report_dir_mb']} MB",
                    flush=True,
                )
            if (
                pending
                and day.sim_s >= pending[0][0] / 24 * sim_hours * 3600
                and day.sim_s < sim_hours * 3600 - period_s
            ):
                _, kind = pending.pop(0)
                outcome = {"at_sim_h": round(day.sim_s / 3600, 3), "kind": kind, **FAULT_ACTIONS[kind](day, session)}
                outcome["done_at_sim_h"] = round(day.sim_s / 3600, 3)
                day.faults.append(outcome)
                print(f"soak-day: fault {outcome}", flush=True)
            time.sleep(0.2)


RESTARTED_BY = (("up", None), ("router", "router"), (BESIDE_NAME, "service"))
"""Each process sampled, and the fault that starts it again (whose last one its memory counts from)."""


def summary(
    day: Day, command: list[str], wall_s: float, errands_sent: dict[str, Any], max_size_mb: float, warm_up_h: float
) -> dict[str, Any]:
    report_dir = day.report_dir
    assert day.up is not None
    report = json.loads((report_dir / "report.json").read_text())
    health = report.get("health") or {}
    kept_goals = report.get("goals") or []
    return {
        "command": "invent " + " ".join(command),
        "exit_code": day.up.returncode,
        "wall_time_s": round(wall_s, 1),
        "wall_time_min": round(wall_s / 60, 1),
        "sim_time_s": report.get("sim_time_s"),
        "errands": errands_sent,
        "goals": {outcome: len(ids) for outcome, ids in day.outcomes.items()},
        "goals_not_completed": {outcome: ids for outcome, ids in day.outcomes.items() if outcome != "completed"},
        "goals_through_the_router": {outcome: len(ids) for outcome, ids in day.outcomes_through_the_router.items()},
        "goals_missed_through_the_router": sorted(
            set(day.outcomes.get("completed", [])) - set(day.outcomes_through_the_router.get("completed", []))
        ),
        "goals_in_the_kept_recording": {
            "count": len(kept_goals),
            "not_completed": [
                {key: goal.get(key) for key in ("id", "outcome", "reason")}
                for goal in kept_goals
                if goal.get("outcome") != "completed"
            ],
        },
        "outcome": report.get("outcome"),
        "restarts": report.get("restarts"),
        "internal_errors": {name: entry["internal_errors"] for name, entry in health.get("services", {}).items()},
        "bad_inputs": {name: entry["bad_inputs"] for name, entry in health.get("services", {}).items()},
        "torques": health.get("torques"),
        "lockstep": health.get("lockstep"),
        "faults": day.faults,
        "router_starts": day.router_starts,
        "memory_growth_mb_per_sim_hour": {
            name: growth(day.samples, name, since(day.faults, kind, warm_up_h)) for name, kind in RESTARTED_BY
        },
        "memory_growth_mb_per_sim_hour_past_the_burst_high_water": {
            name: growth(day.samples, name, past_high_water(day.faults, kind, warm_up_h)) for name, kind in RESTARTED_BY
        },
        "memory_steps_at_bursts": steps_at_bursts(day.samples, day.faults),
        "record_max_size_mb": max_size_mb,
        "report_dir_max_mb": max((s["report_dir_mb"] for s in day.samples), default=None),
        "run_mcap_mb": round(sum(p.stat().st_size for p in report_dir.glob("run*.mcap")) / 1e6, 1),
        "rotated": report.get("rotated"),
        "samples": day.samples,
        "last_lines": day.tail[-30:],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--sim-hours", type=float, default=24.0, help="simulated hours of errands (default 24)")
    parser.add_argument("--period", type=float, default=120.0, help="simulated seconds between errands (120)")
    parser.add_argument("--sample-every", type=float, default=30.0, help="wall seconds between samples (30)")
    parser.add_argument("--keep", metavar="DIR", help="keep the run's directory here (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temporary:
        work = Path(args.keep) if args.keep else Path(temporary)
        work.mkdir(parents=True, exist_ok=True)
        result = soak_day(args.sim_hours, args.period, args.sample_every, work)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({key: value for key, value in result.items() if key != "samples"}, indent=2))
    fine = (
        result["exit_code"] == 0
        and all(fault["survived"] for fault in result["faults"])
        and result["goals"].get("completed") == result["errands"]["in_goal_file"]
        and not any(result["internal_errors"].values())
        and all(
            growth is not None and growth < FLAT_MB_PER_HOUR
            for growth in result["memory_growth_mb_per_sim_hour_past_the_burst_high_water"].values()
        )
        and (result["report_dir_max_mb"] or 0.0) <= result["record_max_size_mb"]
    )
    return 0 if fine else 1


if __name__ == "__main__":
    sys.exit(main())
