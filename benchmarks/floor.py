"""The floor zenoh sets: a bare zenoh-python ping-pong between two processes.

No exchange between two Python processes over zenoh can be faster than one round trip, and one
lockstep step of the separate-process loop needs at least one (wheel angles out, torque back).
So the loop's steps per second are measured against this, in the same run: two peer sessions
configured as the services' are (``session_config``: peer, multicast scouting off, a router to
connect to, a loopback listener; they then talk directly), a payload the size of a wheel-angle
sample, each side taking samples from a FIFO channel on its own thread as the services do, one
message in flight. Run as ``python -m benchmarks.floor ping|pong ENDPOINT [SECONDS [RATE_HZ]]``;
:func:`measure` starts the router and both sides.

Paced (``rate_hz``), the ping sends at that rate of wall time, as the realtime simulator does,
and the figures include the round trips longer than a period: what a realtime loop at that rate
would count as late torques if it did nothing but the exchange.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from services.runtime.session import has_match, open_session, session_config

REPO = Path(__file__).resolve().parent.parent
PING_KEY = "bench/floor/ping"
PONG_KEY = "bench/floor/pong"
PAYLOAD = b'{"tm":{"sec":12,"nsec":345000000},"data":[1.234567,2.345678]}'
"""About 60 bytes, the size of a wheel-angle sample's JSON."""
CHANNEL = 256
START_TIMEOUT_S = 20.0


def _cpu_seconds() -> float:
    times = os.times()
    return times.user + times.system


def pong(endpoint: str) -> int:
    """Answer every ping with a pong until the ping says it is done (an empty payload)."""
    with open_session(session_config(connect=[endpoint])) as session:
        pings = session.declare_subscriber(PING_KEY, zenoh.handlers.FifoChannel(CHANNEL))
        publisher = session.declare_publisher(PONG_KEY)
        print("ready", flush=True)
        while True:
            sample = pings.recv()
            payload = sample.payload.to_bytes()
            if not payload:
                return 0
            publisher.put(payload)


def ping(endpoint: str, seconds: float, rate_hz: float | None = None) -> int:
    """Ping, wait for the pong, again (at ``rate_hz`` if given, else at once), for ``seconds``;
    print the figures as one JSON line."""
    with open_session(session_config(connect=[endpoint])) as session:
        pongs = session.declare_subscriber(PONG_KEY, zenoh.handlers.FifoChannel(CHANNEL))
        publisher = session.declare_publisher(PING_KEY)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not has_match(publisher):
            if time.monotonic() > deadline:
                print(json.dumps({"error": "the pong side never subscribed"}), flush=True)
                return 1
            time.sleep(0.01)
        for _ in range(100):  # warm up the routes both ways
            publisher.put(PAYLOAD)
            pongs.recv()
        latencies: list[int] = []
        cpu_start, started = _cpu_seconds(), time.perf_counter()
        end = started + seconds
        period = None if rate_hz is None else 1.0 / rate_hz
        while True:
            if period is not None:
                while (wait := started + len(latencies) * period - time.perf_counter()) > 0.0:
                    time.sleep(wait)
            sent = time.perf_counter_ns()
            publisher.put(PAYLOAD)
            pongs.recv()
            latencies.append(time.perf_counter_ns() - sent)
            if len(latencies) % 100 == 0 and time.perf_counter() >= end:
                break
        elapsed, cpu = time.perf_counter() - started, _cpu_seconds() - cpu_start
        publisher.put(b"")
        latencies.sort()
        figures = {
            "round_trips_per_s": len(latencies) / elapsed,
            "p50_us": latencies[len(latencies) // 2] / 1000,
            "p99_us": latencies[int(len(latencies) * 0.99)] / 1000,
            "max_us": latencies[-1] / 1000,
            "ping_cpu_us_per_round_trip": cpu / len(latencies) * 1e6,
            "round_trips": len(latencies),
        }
        if period is not None:
            longer = sum(latency > period * 1e9 for latency in latencies)
            figures["longer_than_period_fraction"] = longer / len(latencies)
        print(json.dumps(figures), flush=True)
        return 0


def measure(seconds: float, endpoint: str, rate_hz: float | None = None) -> dict[str, float]:
    """A router, the pong side, then the ping side for ``seconds`` (paced at ``rate_hz`` if
    given): its figures."""
    command = [sys.executable, "-m"]
    router = subprocess.Popen(
        [*command, "services.cli", "router", "--listen", endpoint, "--log-level", "error"],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    responder = subprocess.Popen(
        [*command, "benchmarks.floor", "pong", endpoint], cwd=REPO, stdout=subprocess.PIPE, text=True
    )
    try:
        assert responder.stdout is not None
        if responder.stdout.readline().strip() != "ready":
            raise RuntimeError("the floor's pong side did not start")
        result = subprocess.run(
            [
                *command,
                "benchmarks.floor",
                "ping",
                endpoint,
                str(seconds),
                *([] if rate_hz is None else [str(rate_hz)]),
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=seconds + 60,
            check=False,
        )
        figures = json.loads(result.stdout.strip().splitlines()[-1]) if result.stdout.strip() else {}
        if result.returncode != 0 or "error" in figures:
            raise RuntimeError(f"the floor's ping side failed: {figures.get('error') or result.stderr[-500:]}")
        responder.wait(timeout=10)
        return figures
    finally:
        for process in (responder, router):
            if process.poll() is None:
                process.terminate()
                process.wait(timeout=10)


if __name__ == "__main__":
    role, address = sys.argv[1], sys.argv[2]
    if role == "pong":
        sys.exit(pong(address))
    sys.exit(ping(address, float(sys.argv[3]), float(sys.argv[4]) if len(sys.argv) > 4 else None))
