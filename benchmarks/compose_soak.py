"""The compose soak (``make compose-soak``; never part of ``make test``): ``docker compose up``, the
default profile, left running ``--duration`` seconds (an hour by default), watched from the host
through the router's published port with the observer's and the operator's credentials.

Every ``--sample-every`` seconds: each container's memory (``docker stats``) and restart count, and
the services' status (the sim's steps and late steps, every service's ``internal_errors``). At a third
and at two thirds of the run the control path's container (the sim and the motor composed; with
``--split``, compose.split.yaml's: the motor's, then the sim's) is killed (SIGKILL to its process from
the host, as a crash would) after an operator's ``stop``: docker restarts it (``restart:
unless-stopped``); the motor must come back ``stopped`` (the latch kept in its state volume) and the
robot stay put until the operator's ``clear``, after which the loop resumes (the drive's next
target moves the robot). At the end: each container's memory growth per hour after the warm-up (a
least-squares slope over each life of the container, its first minutes left out), the restarts, the internal errors, the late fraction per sample interval, and
each kill's figures. Ctrl-C ends it early with what it has (``interrupted``). Writes
``benchmarks/results/compose-soak.json``; exit 0 when every check
holds, 1 otherwise. Figures in benchmarks/README.md, "Compose".
"""

from __future__ import annotations

import argparse
import collections
import itertools
import json
import os
import signal
import statistics
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from benchmarks import compose_stack
from benchmarks.compose_stack import KEYS, Stack
from benchmarks.loop import service_status as status
from benchmarks.machine import describe
from benchmarks.soak import SERVICES, slope_per_hour
from schemas.keys import Service
from schemas.status import MotorStatus, SimStatus
from schemas.status_kinds import status_type
from schemas.topics import Method, MethodFamily
from services.runtime.session import stop_on_signals

RESULTS = Path(__file__).resolve().parent / "results" / "compose-soak.json"
MEMORY_LIMIT_MB_PER_H = 5.0
RESTART_TIMEOUT_S = 60.0
STILL_S = 5.0
"""How long the robot is watched standing still after its motor (or sim) came back stopped."""
MOVED_M = 0.01


def _call(session: zenoh.Session, method: Method) -> bool:
    key = KEYS.method(MethodFamily.GUI, method)
    return any(reply.ok is not None for reply in session.get(key, payload=b"{}", timeout=5.0))


def _wait(predicate: Any, timeout: float, what: str) -> float:
    """Seconds until ``predicate()`` held; RuntimeError naming ``what`` after ``timeout``."""
    started = time.monotonic()
    while time.monotonic() - started < timeout:
        if predicate():
            return time.monotonic() - started
        time.sleep(0.2)
    raise RuntimeError(f"{what}: not within {timeout:.0f} s")


def _pose(observer: zenoh.Session) -> tuple[float, float] | None:
    sim = status(observer, Service.SIM, SimStatus, KEYS)
    return None if sim is None else (sim.pose.x, sim.pose.y)


def _moved(since: tuple[float, float] | None, now: tuple[float, float] | None) -> float:
    if since is None or now is None:
        return float("nan")
    return ((now[0] - since[0]) ** 2 + (now[1] - since[1]) ** 2) ** 0.5


def _motor_state(observer: zenoh.Session) -> str | None:
    motor = status(observer, Service.MOTOR, MotorStatus, KEYS)
    return None if motor is None else motor.state


SPLIT = "compose.split.yaml"
KILLED = {"composed": ("control", "control"), "split": (str(Service.MOTOR), str(Service.SIM))}
"""The containers killed at a third and at two thirds of the run, by layout."""
SERVED_BY = {
    "control": (Service.SIM, Service.MOTOR),
    str(Service.MOTOR): (Service.MOTOR,),
    str(Service.SIM): (Service.SIM,),
}
"""What answers again once a killed container is back."""


def kill_and_restart(stack: Stack, name: str, observer: zenoh.Session, operator: zenoh.Session) -> dict[str, Any]:
    """Stop the robot, kill container ``name``'s process, and check what the soak's docstring says."""
    container = stack.container(name)
    restarts_before = compose_stack.inspect(container)["RestartCount"]
    figures: dict[str, Any] = {"container": name, "stop_acknowledged": _call(operator, Method.STOP)}
    _wait(lambda: _motor_state(observer) == "stopped", 10.0, "the motor stopped")
    os.kill(compose_stack.inspect(container)["State"]["Pid"], signal.SIGKILL)
    killed = time.monotonic()
    _wait(
        lambda: (
            compose_stack.inspect(container)["RestartCount"] > restarts_before
            and compose_stack.inspect(container)["State"]["Running"]
        ),
        RESTART_TIMEOUT_S,
        f"{name}'s container restarted",
    )
    for service in SERVED_BY[name]:
        _wait(
            lambda s=service: status(observer, s, status_type(s), KEYS) is not None,
            RESTART_TIMEOUT_S,
            f"{service} answering again",
        )
    figures["back_after_s"] = round(time.monotonic() - killed, 1)
    figures["state_after_restart"] = _motor_state(observer)
    before = _pose(observer)
    time.sleep(STILL_S)
    figures["moved_while_stopped_m"] = _moved(before, _pose(observer))
    figures["still_stopped"] = _motor_state(observer) == "stopped"
    figures["clear_acknowledged"] = _call(operator, Method.CLEAR)
    cleared, at_clear = time.monotonic(), _pose(observer)
    try:
        _wait(lambda: _moved(at_clear, _pose(observer)) > MOVED_M, 30.0, "the loop resuming after clear")
        figures["resumed_after_clear_s"] = round(time.monotonic() - cleared, 1)
    except RuntimeError:
        figures["resumed_after_clear_s"] = None
    figures["ok"] = bool(
        figures["stop_acknowledged"]
        and figures["state_after_restart"] == "stopped"
        and figures["still_stopped"]
        and figures["moved_while_stopped_m"] < MOVED_M
        and figures["clear_acknowledged"]
        and figures["resumed_after_clear_s"] is not None
    )
    return figures


def sample(stack: Stack, containers: dict[str, str], observer: zenoh.Session, elapsed: float) -> dict[str, Any]:
    taken: dict[str, Any] = {"t_s": round(elapsed, 1), "containers": {}, "internal_errors": {}}
    for service, container in containers.items():
        inspected = compose_stack.inspect(container)
        memory = compose_stack.memory_bytes(container)
        taken["containers"][service] = {
            "memory_mb": None if memory is None else round(memory / 1e6, 2),
            "restarts": inspected["RestartCount"],
            "running": inspected["State"]["Running"],
        }
    for service in SERVICES:
        answered = status(observer, service, status_type(service), KEYS)
        taken["internal_errors"][str(service)] = None if answered is None else answered.internal_errors
        if isinstance(answered, SimStatus):
            taken["steps"] = answered.steps
            taken["late_steps"] = answered.counters.realtime_late_steps
    return taken


def _segments(samples: list[dict[str, Any]], service: str, warm_up_s: float) -> list[list[tuple[float, float]]]:
    """``service``'s memory (seconds, MB) in each life of its container (a restart starts a new one),
    without each life's first ``warm_up_s``."""
    lives: list[list[tuple[float, float]]] = []
    restarts, born = None, 0.0
    for entry in samples:
        taken = entry["containers"].get(service)
        if taken is None or taken["memory_mb"] is None:
            continue
        if taken["restarts"] != restarts:
            restarts, born = taken["restarts"], entry["t_s"]
            lives.append([])
        if entry["t_s"] - born >= warm_up_s:
            lives[-1].append((entry["t_s"], taken["memory_mb"]))
    return [life for life in lives if len(life) >= 2 and life[-1][0] - life[0][0] >= warm_up_s]


def summary(samples: list[dict[str, Any]], warm_up_s: float, kills: list[dict[str, Any]]) -> dict[str, Any]:
    growth = {
        service: [round(slope_per_hour(life), 2) for life in _segments(samples, service, warm_up_s)]
        for service in samples[0]["containers"]
    }
    intervals = [
        (b["late_steps"] - a["late_steps"], b["steps"] - a["steps"])
        for a, b in itertools.pairwise(samples)
        if "steps" in a and "steps" in b and b["steps"] > a["steps"] and b["late_steps"] >= a["late_steps"]
    ]
    late = [late_steps / steps for late_steps, steps in intervals]
    restarts = {service: samples[-1]["containers"][service]["restarts"] for service in samples[-1]["containers"]}
    killed = collections.Counter(kill["container"] for kill in kills)
    errors = [value for entry in samples for value in entry["internal_errors"].values() if value]
    return {
        "memory_growth_mb_per_h": growth,
        "restarts": restarts,
        "internal_errors_max": max(errors, default=0),
        "late_fraction_per_interval": {
            "min": min(late, default=None),
            "median": statistics.median(late) if late else None,
            "max": max(late, default=None),
        },
        "late_fraction_whole": sum(late_steps for late_steps, _ in intervals) / sum(steps for _, steps in intervals)
        if intervals
        else None,
        "checks": {
            "memory_flat": all(value < MEMORY_LIMIT_MB_PER_H for lives in growth.values() for value in lives),
            "no_other_restart": all(count == killed[service] for service, count in restarts.items()),
            "no_internal_error": not errors,
            "kills": all(kill["ok"] for kill in kills) and len(kills) == 2,
        },
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.compose_soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3600.0, metavar="S", help="wall seconds (3600)")
    parser.add_argument("--sample-every", type=float, default=30.0, metavar="S", help="seconds between looks (30)")
    parser.add_argument("--warm-up", type=float, default=300.0, metavar="S", help="memory slope after (300)")
    parser.add_argument("--output", type=Path, default=RESULTS, metavar="FILE", help=f"default {RESULTS}")
    parser.add_argument("--split", action="store_true", help=f"with {SPLIT}: the sim and the motor a container each")
    args = parser.parse_args(argv)
    try:
        compose = compose_stack.compose_command()
    except compose_stack.DockerMissing as missing:
        print(f"Docker is not here ({missing}): no compose soak")
        return 1
    compose_stack.role_config("operator")
    layout = "split" if args.split else "composed"
    stack = Stack(compose, [compose_stack.REPO / SPLIT] if args.split else [])
    samples: list[dict[str, Any]] = []
    kills: list[dict[str, Any]] = []
    first, second = KILLED[layout]
    kill_at = {args.duration / 3: first, 2 * args.duration / 3: second}
    stop = stop_on_signals()
    elapsed = 0.0
    try:
        stack.up()
        running = {service: stack.container(service) for service in stack.services()}
        containers = {service: container for service, container in running.items() if container}
        with compose_stack.observer_session() as observer, compose_stack.observer_session("operator") as operator:
            compose_stack.wait_for_steps(observer)
            started = time.monotonic()
            next_sample = 0.0
            while (elapsed := time.monotonic() - started) < args.duration and not stop.is_set():
                for at, name in list(kill_at.items()):
                    if elapsed >= at:
                        del kill_at[at]
                        print(f"{elapsed:7.0f} s  killing {name}'s container (the robot stopped first)", flush=True)
                        try:
                            kills.append(kill_and_restart(stack, name, observer, operator))
                        except RuntimeError as failed:
                            kills.append({"container": name, "ok": False, "failed": str(failed)})
                        print(f"          {json.dumps(kills[-1])}", flush=True)
                if elapsed >= next_sample:
                    samples.append(sample(stack, containers, observer, elapsed))
                    memory = {name: entry["memory_mb"] for name, entry in samples[-1]["containers"].items()}
                    print(
                        f"{elapsed:7.0f} s  late {samples[-1].get('late_steps')}/{samples[-1].get('steps')}  MB {memory}",
                        flush=True,
                    )
                    next_sample += args.sample_every
                stop.wait(1.0)
            samples.append(sample(stack, containers, observer, time.monotonic() - started))
    finally:
        stack.down()
    result = {
        "machine": describe(),
        "layout": layout,
        "duration_s": args.duration,
        "ran_s": round(elapsed, 1),
        "interrupted": stop.is_set(),
        "summary": summary(samples, args.warm_up, kills),
        "kills": kills,
        "samples": samples,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result["summary"], indent=2))
    print(f"wrote {args.output}")
    return 0 if all(result["summary"]["checks"].values()) and not stop.is_set() else 1


if __name__ == "__main__":
    raise SystemExit(main())
