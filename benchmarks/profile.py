"""``make profile``: where each process of the lockstep loop spends its time.

Starts the loop as ``make bench`` does (router, motor, odometry, localization, drive, sim, each
its own process; with ``--composed``, ``invent up --composed --no-record``, one process), lets it
warm up, then samples each service process in turn with py-spy (``py-spy record --format raw``,
non-blocking: one sampler at a time, so the loop runs nearly as fast as unsampled) and prints,
per process, its CPU share while sampled and the functions with the most samples: on top of the
stack (self) and anywhere in it (total). Needs py-spy
(``pip install py-spy``; ``make profile`` installs it).
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import loop
from schemas.keys import Service
from services.runtime.session import open_session, session_config


def _profile(pid: int, seconds: float, rate: int, output: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            "py-spy", "record", "--pid", str(pid), "--duration", str(int(seconds)), "--rate", str(rate),
            "--format", "raw", "--nonblocking", "--output", str(output),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds by thread name of process ``pid`` (Python's threads are all named after the
    program, ``python``; zenoh's after their task: ``tx`` batching and sending, ``rx`` receiving,
    ``net``, ``acc``, ``app``), from /proc (Linux)."""
    ticks = os.sysconf("SC_CLK_TCK")
    by_name: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        group = name.rstrip("0123456789").rstrip("-") or name
        by_name[group] = by_name.get(group, 0.0) + (int(fields[11]) + int(fields[12])) / ticks
    return by_name


def _frame(frame: str) -> str:
    """``function (path/file.py:line)`` -> ``function (file.py)``: a function, whatever the line."""
    name, _, where = frame.partition(" (")
    return f"{name} ({Path(where.rstrip(')')).name.split(':')[0]})" if where else name


WAITING = frozenset({"NodeInput.receive", "Condition.wait", "Event.wait", "Executor._wait", "Thread._bootstrap"})
"""Leaves where a thread waits (a channel's receive, a lock): py-spy counts the time in zenoh's
receive as running, since it is native code; these samples are left out of the work listed."""


def summarise(raw: str, top: int) -> tuple[int, int, list[tuple[str, int]], list[tuple[str, int]]]:
    """(samples, samples at work, the most frequent leaves at work, the most frequent functions
    anywhere in a working stack)."""
    leaves: collections.Counter[str] = collections.Counter()
    anywhere: collections.Counter[str] = collections.Counter()
    samples = working = 0
    for line in raw.splitlines():
        stack, _, count_text = line.rpartition(" ")
        if not stack or not count_text.isdigit():
            continue
        count = int(count_text)
        frames = [_frame(frame) for frame in stack.split(";")]
        samples += count
        if frames[-1].split(" (")[0] in WAITING:
            continue
        working += count
        leaves[frames[-1]] += count
        for name in set(frames):
            anywhere[name] += count
    return samples, working, leaves.most_common(top), anywhere.most_common(top)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--warmup", type=float, default=3.0, metavar="S", help="wall seconds before sampling")
    parser.add_argument("--seconds", type=float, default=8.0, metavar="S", help="wall seconds each process is sampled")
    parser.add_argument("--rate", type=int, default=200, metavar="HZ", help="samples per second")
    parser.add_argument("--top", type=int, default=12, metavar="N", help="functions listed per process")
    parser.add_argument("--flags", nargs="*", default=[], metavar="FLAG", help="sim flags, e.g. --mode realtime")
    parser.add_argument("--composed", action="store_true", help="profile invent up --composed --no-record")
    args = parser.parse_args(argv)
    if shutil.which("py-spy") is None:
        print("py-spy is not on PATH: pip install py-spy", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as folder:
        directory = Path(folder)
        run: loop.UpRun | loop.ServicesRun
        if args.composed:
            run = loop.UpRun([loop.COMPOSED_FLAG, loop.NO_RECORD_FLAG, *args.flags], directory)
        else:
            run = loop.ServicesRun(args.flags, directory)
        windows: dict[str, tuple[float, int, dict[str, float]]] = {}
        try:
            with open_session(session_config(connect=[run.endpoint])) as session:
                if isinstance(run, loop.ServicesRun):
                    run.start_loop(session)
                    processes = {name: process for name, process in run.processes.items() if name != "router"}
                else:
                    processes = {"composed": run.process}
                loop._wait(lambda: loop._alive(session, Service.SIM), "the sim", run)
                time.sleep(args.warmup)
                for name, process in processes.items():
                    before, threads_before, started = (
                        loop.sim_status(session),
                        thread_cpu(process.pid),
                        time.monotonic(),
                    )
                    _profile(process.pid, args.seconds, args.rate, directory / f"{name}.txt").wait(args.seconds + 60)
                    wall, after, threads_after = (
                        time.monotonic() - started,
                        loop.sim_status(session),
                        thread_cpu(process.pid),
                    )
                    steps = (0 if after is None else after.steps) - (0 if before is None else before.steps)
                    threads = {key: value - threads_before.get(key, 0.0) for key, value in threads_after.items()}
                    windows[name] = (wall, steps, threads)
        finally:
            run.stop()
        for name, (wall, steps, threads) in windows.items():
            cpu = sum(threads.values())
            print(
                f"## {name}: {cpu / wall:.0%} of a core, {1e6 * cpu / max(steps, 1):,.0f} µs CPU per step "
                f"(the loop at {steps / wall:,.0f} steps/s while it was sampled)"
            )
            by_thread = sorted(threads.items(), key=lambda item: -item[1])
            print(
                "CPU µs per step, by thread: "
                + ", ".join(f"{key} {1e6 * value / max(steps, 1):,.0f}" for key, value in by_thread)
            )
            samples, working, leaves, totals = summarise((directory / f"{name}.txt").read_text(), args.top)
            print(f"Python: {samples} samples, {working} at work (not waiting); of those, self | total")
            for (leaf, count), (function, total) in zip(leaves, totals, strict=False):
                print(f"  {100 * count / working:5.1f} % {leaf:<60} | {100 * total / working:5.1f} % {function}")
            print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
