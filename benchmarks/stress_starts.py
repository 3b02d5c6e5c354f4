"""Starts under stress (``make stress``; never part of ``make test``): ``invent up --no-record``
started and stopped ``--starts`` times in a row (default 100), each on a port chosen as the bench
and the tests choose theirs (:func:`~services.runtime.session.free_port`), with its own zenoh
session joining the run as the bench's does.

A start counts when the loop runs (a progress line past 0.1 s of simulation), Ctrl-C (SIGINT)
then stops it with ``up``'s interrupted exit (130), and no process of it is left. Any other end is
a failure, reported with the run's last lines (a router that cannot listen says why). Exits 1
when any start failed. Figures in benchmarks/README.md, "Starts".
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from services.runtime.session import free_port, open_session, session_config

INTERRUPTED = 130
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 30.0
RUNNING = re.compile(r"sim +(\d+\.\d+) s \|")
RESULTS = Path(__file__).resolve().parent / "results" / "stress_starts.json"


def one_start() -> tuple[bool, str, float]:
    """(whether the run started and stopped cleanly, why not, seconds to the loop's first progress)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    process = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "up", "--no-record", "--scenario", "square", "--listen", endpoint],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    lines: list[str] = []
    running = threading.Event()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.append(line)
            match = RUNNING.search(line)
            if match and float(match.group(1)) > 0.1:
                running.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    # the bench joins the run with a session of its own, at once: so does this
    with open_session(session_config(connect=[endpoint])):
        while not running.wait(0.1) and process.poll() is None and time.monotonic() - started < START_TIMEOUT_S:
            pass
    to_running = time.monotonic() - started
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        code = process.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        code = process.wait()
    reader.join(5.0)
    if not running.is_set():
        return False, f"the loop did not run (exit {code}):\n{''.join(lines[-12:])}", to_running
    if code != INTERRUPTED:
        return False, f"stopped with exit {code}, not {INTERRUPTED}:\n{''.join(lines[-12:])}", to_running
    return True, "", to_running


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.stress_starts", description=__doc__.split("\n\n")[0])
    parser.add_argument("--starts", type=int, default=100, help="starts in a row (default 100)")
    parser.add_argument("--output", type=Path, default=RESULTS, help=f"(default {RESULTS})")
    args = parser.parse_args(argv)
    failures: list[dict[str, object]] = []
    times: list[float] = []
    began = time.monotonic()
    for index in range(1, args.starts + 1):
        ok, why, to_running = one_start()
        times.append(to_running)
        if not ok:
            failures.append({"start": index, "why": why})
            print(f"start {index}: FAILED: {why}", flush=True)
        print(
            f"start {index}/{args.starts}: {'ok' if ok else 'FAILED'} ({to_running:.2f} s to the loop running)",
            flush=True,
        )
    result = {
        "starts": args.starts,
        "failures": len(failures),
        "failed": failures,
        "seconds_to_running": {"min": min(times), "median": sorted(times)[len(times) // 2], "max": max(times)},
        "wall_s": time.monotonic() - began,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({key: value for key, value in result.items() if key != "failed"}, indent=2))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
