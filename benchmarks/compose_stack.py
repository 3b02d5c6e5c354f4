"""The compose stack driven from the host, for ``make compose-bench`` and ``make compose-soak``:
whether Docker is here, ``up`` and ``down`` with override files, the containers' ids, memory and
restarts, and a zenoh session through the router's published port with a role's credentials."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh

from benchmarks.loop import sim_status
from schemas.keys import Keys
from schemas.status import SimStatus
from services.runtime.session import open_session

REPO = Path(__file__).resolve().parent.parent
SECRETS = REPO / "docker" / "secure" / "secrets"
KEYS = Keys()
START_TIMEOUT_S = 120.0


class DockerMissing(RuntimeError):
    """Docker (the daemon, or a compose command) is not on this machine: the section is skipped."""


def compose_command() -> list[str]:
    """``docker compose`` (the v2 plugin) or ``docker-compose`` (v1), whichever is here, with a
    daemon that answers; DockerMissing naming what is not."""
    if shutil.which("docker") is None:
        raise DockerMissing("no `docker` command")
    info = subprocess.run(
        ["docker", "info", "--format", "{{.ServerVersion}}"], check=False, capture_output=True, text=True
    )
    if info.returncode != 0:
        raise DockerMissing(f"the Docker daemon does not answer ({info.stderr.strip().splitlines()[-1:]})")
    if subprocess.run(["docker", "compose", "version"], check=False, capture_output=True).returncode == 0:
        return ["docker", "compose"]
    if shutil.which("docker-compose") is not None:
        return ["docker-compose"]
    raise DockerMissing("neither `docker compose` nor `docker-compose`")


def role_config(role: str) -> Path:
    """A role's credentials made by ``make secrets``; SystemExit when they were not made."""
    path = SECRETS / f"{role}.json5"
    if not path.is_file():
        raise SystemExit(f"{path} is missing: run `make secrets` first")
    return path


class Stack:
    """``compose.yaml`` (and ``overrides``, compose files merged over it) up until closed."""

    def __init__(self, compose: list[str], overrides: Sequence[Path] = (), profiles: Sequence[str] = ()) -> None:
        files = [REPO / "compose.yaml", *overrides]
        self.command = [*compose, *(arg for path in files for arg in ("-f", str(path)))]
        self.environment = {**os.environ, **({"COMPOSE_PROFILES": ",".join(profiles)} if profiles else {})}

    def run(self, *args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
        result = subprocess.run(
            [*self.command, *args], check=False, cwd=REPO, env=self.environment, capture_output=True, text=True
        )
        if check and result.returncode != 0:
            raise RuntimeError(f"{' '.join(args)}: {result.stderr.strip()[-600:]}")
        return result

    def up(self) -> None:
        self.run("up", "-d")

    def down(self) -> None:
        self.run("down", check=False)

    def container(self, service: str) -> str:
        """The id of ``service``'s container."""
        return self.run("ps", "-q", service).stdout.strip()

    def services(self) -> list[str]:
        return self.run("ps", "--services").stdout.split()


def inspect(container: str) -> dict[str, Any]:
    result = subprocess.run(["docker", "inspect", container], capture_output=True, text=True, check=True)
    inspected: dict[str, Any] = json.loads(result.stdout)[0]
    return inspected


def memory_bytes(container: str) -> int | None:
    """The container's memory in use, as ``docker stats`` counts it (its cgroup's usage less the
    page cache), or None when it is not running."""
    stats = subprocess.run(
        ["docker", "stats", "--no-stream", "--format", "{{json .}}", container],
        check=False,
        capture_output=True,
        text=True,
    )
    if stats.returncode != 0 or not stats.stdout.strip():
        return None
    used = json.loads(stats.stdout)["MemUsage"].split("/")[0].strip()
    units = {"B": 1, "KiB": 1 << 10, "MiB": 1 << 20, "GiB": 1 << 30, "kB": 1000, "MB": 10**6, "GB": 10**9}
    for unit in sorted(units, key=len, reverse=True):
        if used.endswith(unit):
            return round(float(used[: -len(unit)]) * units[unit])
    return None


@contextmanager
def observer_session(role: str = "observer") -> Iterator[zenoh.Session]:
    """A session through the router's published port (``tcp/127.0.0.1:7447``, the role file's)."""
    with open_session(zenoh.Config.from_file(str(role_config(role)))) as session:
        yield session


def wait_for_steps(session: zenoh.Session, steps: int = 1000, timeout: float = START_TIMEOUT_S) -> SimStatus:
    """The sim's status once it has stepped ``steps`` times; RuntimeError after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sim = sim_status(session, KEYS)
        if sim is not None and sim.steps >= steps:
            return sim
        time.sleep(1.0)
    raise RuntimeError(f"the sim did not step {steps} times within {timeout:.0f} s")


def late_over(session: zenoh.Session, window_s: float) -> dict[str, Any]:
    """The sim's late steps over ``window_s`` of wall time from now."""
    before = sim_status(session, KEYS)
    time.sleep(window_s)
    after = sim_status(session, KEYS)
    if before is None or after is None:
        raise RuntimeError("the sim did not answer its status")
    steps = after.steps - before.steps
    late = after.counters.realtime_late_steps - before.counters.realtime_late_steps
    return {"steps": steps, "late_steps": late, "late_fraction": late / steps if steps else None}
