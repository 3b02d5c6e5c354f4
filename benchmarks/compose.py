"""Compose against bare (``make compose-bench``; never part of ``make test``): the sim's late steps
in realtime at 1 kHz, the square in a loop, with the same services started by ``invent up`` on this
machine and by ``docker compose up``, one cause at a time.

Each case runs alone: started, warmed up (``--warmup``), then the sim's ``realtime_late_steps``
over its steps for ``--window`` seconds of wall time; ``--repeats N`` runs the cases N times,
interleaved (the machine's noise then falls on every case alike), and reports each case's median. Bare cases: ``invent up --mode realtime
--loop`` with or without ``invent view``, the ROS 2 bridge, ``--secure`` (every service a client of
the router with its role's credentials, as in compose), ``--rt``, ``rt.partition`` off, and
``--split`` (the sim and the motor as two processes, as before ``invent up`` composed them). Compose
cases (when Docker is here; the section says so and is skipped when it is not): ``compose.yaml``'s
default profile (the sim and the motor composed in its control container), and the same with one
thing changed by an override file: ``compose.split.yaml`` (the sim and the motor a container each),
the router's CPU left to the system, ``rt.partition`` off, no view, ``compose.rt.yaml`` (real-time
budgets from the daemon).
Needs ``make secrets`` for compose. Writes ``benchmarks/results/compose.json``; figures in
benchmarks/README.md, "Compose".
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
from ruamel.yaml import YAML

from benchmarks import compose_stack
from benchmarks.figures import median
from benchmarks.machine import describe
from services.runtime.session import free_port, open_session, session_config

RESULTS = Path(__file__).resolve().parent / "results" / "compose.json"
INVENT = str(Path(sys.executable).with_name("invent"))
NO_PARTITION = ("--set", "rt.partition=false")


@dataclass(frozen=True)
class Bare:
    """``invent up --mode realtime --loop`` with these flags, and ``invent view`` beside it or not."""

    description: str
    up_flags: tuple[str, ...] = ()
    view: bool = False
    view_flags: tuple[str, ...] = ()
    secure: bool = False


@dataclass(frozen=True)
class Compose:
    """``compose.yaml`` with ``changes`` (an override built from it) or ``files`` merged over it."""

    description: str
    changes: Callable[[dict[str, Any]], dict[str, Any]] | None = None
    files: tuple[str, ...] = ()


def _router_on_any_cpu(compose: dict[str, Any]) -> dict[str, Any]:
    return {"services": {"router": {"cpuset": f"0-{(os.cpu_count() or 1) - 1}"}}}


def _no_partition(compose: dict[str, Any]) -> dict[str, Any]:
    services = {
        name: {"command": [*service["command"], *NO_PARTITION]}
        for name, service in compose["services"].items()
        if service.get("build") or service.get("image") == "invent-zenoh"
        if name != "router"
    }
    return {"services": services}


def _no_view(compose: dict[str, Any]) -> dict[str, Any]:
    return {"services": {"view": {"profiles": ["no-view"]}}}


CASES: dict[str, Bare | Compose] = {
    "bare": Bare("the loop alone (the sim and the motor composed: invent control)"),
    "bare_view": Bare("the loop + invent view (compose's default services)", view=True),
    "bare_split": Bare("the loop alone, the sim and the motor two processes (--split)", ("--split",)),
    "bare_view_no_partition": Bare("the loop + view, rt.partition off", NO_PARTITION, True, NO_PARTITION),
    "bare_ros2_view": Bare("the loop + ROS 2 bridge + view", ("--ros2",), view=True),
    "bare_ros2_view_split": Bare("the loop + ROS 2 bridge + view, --split", ("--ros2", "--split"), view=True),
    "bare_ros2_view_no_partition": Bare(
        "the loop + ROS 2 bridge + view, rt.partition off", ("--ros2", *NO_PARTITION), True, NO_PARTITION
    ),
    "bare_secure_view": Bare(
        "--secure (compose's topology: every service a client of the router) + view", (), True, (), True
    ),
    "bare_rt_view": Bare("--rt + view", ("--rt",), view=True),
    "compose": Compose("docker compose up: the default profile (the control path composed), every container"),
    "compose_split": Compose(
        "compose + compose.split.yaml (the sim and the motor a container each)", files=("compose.split.yaml",)
    ),
    "compose_router_any_cpu": Compose("compose, the router's CPU left to the system", _router_on_any_cpu),
    "compose_no_partition": Compose("compose, rt.partition off", _no_partition),
    "compose_no_view": Compose("compose without the view", _no_view),
    "compose_rt": Compose("compose + compose.rt.yaml (the daemon's real-time budget)", files=("compose.rt.yaml",)),
}


@dataclass
class Outcome:
    description: str
    runs: list[dict[str, Any]] = field(default_factory=list)
    """Each repeat's late steps over the window, with the load average after it."""
    skipped: str | None = None

    @property
    def median_late_fraction(self) -> float | None:
        return median([run.get("late_fraction") for run in self.runs])

    def as_dict(self) -> dict[str, Any]:
        return {**vars(self), "median_late_fraction": self.median_late_fraction}


def _stop(processes: Sequence[subprocess.Popen[bytes]]) -> None:
    for process in reversed(processes):
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def measure_bare(case: Bare, warmup_s: float, window_s: float) -> dict[str, Any]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory(prefix="invent-compose-bench-") as folder:
        # Nothing recorded, as in compose; --secure writes its credentials into runs/<time>/secrets/.
        up = [INVENT, "up", "--mode", "realtime", "--loop", "--no-record", "--listen", endpoint]
        processes = [
            subprocess.Popen(
                [*up, *(["--secure"] if case.secure else []), *case.up_flags],
                cwd=folder,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        ]
        try:
            deadline = time.monotonic() + compose_stack.START_TIMEOUT_S
            while case.secure and not list(Path(folder).glob("runs/*/secrets/observer.json5")):
                if time.monotonic() > deadline:
                    raise RuntimeError("invent up --secure wrote no observer credentials")
                time.sleep(0.2)
            observer = next(Path(folder).glob("runs/*/secrets/observer.json5"), Path())
            connection = ["--zenoh-config", str(observer)] if case.secure else ["--connect", endpoint]
            config = zenoh.Config.from_file(str(observer)) if case.secure else session_config(connect=[endpoint])
            with open_session(config) as session:
                compose_stack.wait_for_steps(session)
                if case.view:
                    view = [INVENT, "view", *connection, "--port", "0", *case.view_flags]
                    processes.append(subprocess.Popen(view, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
                time.sleep(warmup_s)
                return compose_stack.late_over(session, window_s)
        finally:
            _stop(processes)


def measure_compose(case: Compose, compose: list[str], warmup_s: float, window_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="invent-compose-bench-") as folder:
        overrides = [compose_stack.REPO / name for name in case.files]
        if case.changes is not None:
            override = Path(folder) / "override.yaml"
            override.write_text(json.dumps(case.changes(YAML(typ="safe").load(compose_stack.REPO / "compose.yaml"))))
            overrides.append(override)
        stack = compose_stack.Stack(compose, overrides)
        try:
            stack.up()
            with compose_stack.observer_session() as session:
                compose_stack.wait_for_steps(session)
                time.sleep(warmup_s)
                return compose_stack.late_over(session, window_s)
        finally:
            stack.down()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.compose", description=__doc__.split("\n\n")[0])
    parser.add_argument("--window", type=float, default=45.0, metavar="S", help="wall seconds counted (45)")
    parser.add_argument("--warmup", type=float, default=10.0, metavar="S", help="wall seconds before (10)")
    parser.add_argument("--only", metavar="CASE,...", help=f"these cases only, of: {', '.join(CASES)}")
    parser.add_argument(
        "--repeats", type=int, default=1, metavar="N", help="each case N times, the cases interleaved (1)"
    )
    parser.add_argument("--output", type=Path, default=RESULTS, metavar="FILE", help=f"default {RESULTS}")
    args = parser.parse_args(argv)
    names = args.only.split(",") if args.only else list(CASES)
    unknown = [name for name in names if name not in CASES]
    if unknown:
        parser.error(f"--only {','.join(unknown)}: not a case ({', '.join(CASES)})")
    reason = ""
    try:
        compose: list[str] | None = compose_stack.compose_command()
        compose_stack.role_config("observer")
        print(f"Docker: {' '.join(compose or [])}", flush=True)
    except compose_stack.DockerMissing as missing:
        compose, reason = None, str(missing)
        print(f"Docker is not here ({reason}): the compose cases are skipped", flush=True)
    outcomes = {name: Outcome(CASES[name].description) for name in names}
    for repeat in range(args.repeats):
        for name in names:
            case, outcome = CASES[name], outcomes[name]
            if isinstance(case, Compose) and compose is None:
                outcome.skipped = f"Docker is not here ({reason})"
                continue
            print(f"{name} ({repeat + 1} of {args.repeats}): {case.description} ...", flush=True)
            try:
                if isinstance(case, Bare):
                    late = measure_bare(case, args.warmup, args.window)
                else:
                    assert compose is not None
                    late = measure_compose(case, compose, args.warmup, args.window)
            except RuntimeError as error:
                outcome.skipped = f"failed: {error}"
                print(f"  {outcome.skipped}", flush=True)
                continue
            outcome.runs.append({**late, "load_average": [round(value, 2) for value in os.getloadavg()]})
            print(f"  {100 * late['late_fraction']:.2f} % ({late['late_steps']}/{late['steps']})", flush=True)
    print("median late fraction of each case:")
    for name, outcome in outcomes.items():
        typical = outcome.median_late_fraction
        print(f"  {name:32} {'-' if typical is None else f'{100 * typical:.2f} %'}  {outcome.skipped or ''}")
    results = {
        "machine": describe(),
        "window_s": args.window,
        "warmup_s": args.warmup,
        "repeats": args.repeats,
        "cases": {name: outcome.as_dict() for name, outcome in outcomes.items()},
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
