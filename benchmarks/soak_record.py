"""A recording that keeps the newest, left running (``python -m benchmarks.soak_record``; never part of
``make test``): ``invent up --loop`` (``--goals --mode lockstep`` with ``--goals``), which keeps the newest
by default, with the robot description's other defaults (and ``--ros2 --record-ros2`` unless
``--no-ros2``) until ``--sim-hours`` of simulation time, then Ctrl-C. Every ``--sample-every`` seconds it sums the run's journals (both
budgets: ``journals/`` and ``bag-journals/``); at the end it checks that ``run.mcap``'s files and the
bag's stay within ``record.max_size``, that each file opens alone in ``mcap``'s reader, that the bag
opens in rosbags' reader, that ``report.json`` says which span the recording covers, and that
``invent report`` reads the split recording again. Writes
``benchmarks/results/soak_record.json``; docs/recording.md, "Keeping the newest", quotes it.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from services.config import load_config
from services.runtime.session import free_port

RESULTS = Path(__file__).resolve().parent / "results" / "soak_record.json"
PROGRESS = re.compile(r"sim +([\d.]+) s \|")
MB = 1_000_000
END_TIMEOUT_S = 1800.0
"""How long the run may take, once stopped, to write its recording, bag and report."""


def _size(directory: Path) -> int:
    total = 0
    for path in directory.rglob("*"):
        try:
            total += path.stat().st_size if path.is_file() else 0
        except FileNotFoundError:  # removed meanwhile: that is the point
            continue
    return total


def _readable_alone(path: Path) -> int:
    with path.open("rb") as file:
        return sum(1 for _ in make_reader(file).iter_messages())


def _bag_messages(bag: Path) -> int:
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        return sum(1 for _ in reader.messages())


def soak(
    sim_hours: float, sample_every_s: float, ros2: bool, report_dir: Path, commander: list[str], up_args: list[str]
) -> dict[str, Any]:
    max_size = load_config(None, {"record.keep": "newest"}).record.max_size or 0.0
    command = [sys.executable, "-m", "services.cli", "up", *commander, "--report", str(report_dir), *up_args]
    command += ["--listen", f"tcp/127.0.0.1:{free_port()}", *(["--ros2", "--record-ros2"] if ros2 else [])]
    started = time.monotonic()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert process.stdout is not None
    journals_max = {"journals": 0, "bag-journals": 0}
    sim_s, next_sample = 0.0, 0.0
    lines: list[str] = []
    for line in process.stdout:
        lines.append(line)
        if (found := PROGRESS.search(line)) is not None:
            sim_s = float(found.group(1))
        if time.monotonic() >= next_sample:
            next_sample = time.monotonic() + sample_every_s
            for name, largest in journals_max.items():
                journals_max[name] = max(largest, _size(report_dir / name))
        if sim_s >= sim_hours * 3600:
            process.send_signal(signal.SIGINT)
            break
    rest, _ = process.communicate(timeout=END_TIMEOUT_S)
    parts = sorted(report_dir.glob("run*.mcap"))
    report = json.loads((report_dir / "report.json").read_text())
    bag = report_dir / "rosbag2"
    again = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "report",
            str(report_dir / "run.mcap"),
            "--output-dir",
            str(report_dir / "again"),
        ],
        capture_output=True,
        text=True,
        timeout=END_TIMEOUT_S,
        check=False,
    )
    return {
        "command": " ".join(command[2:]),
        "exit_code": process.returncode,
        "wall_time_s": round(time.monotonic() - started, 1),
        "sim_time_s": report["sim_time_s"],
        "max_size_mb": max_size,
        "journals_max_mb": {name: round(size / MB, 1) for name, size in journals_max.items()},
        "run_mcap_files": len(parts),
        "run_mcap_mb": round(sum(part.stat().st_size for part in parts) / MB, 1),
        "each_file_readable_alone": all(_readable_alone(part) > 0 for part in parts),
        "bag_mb": round(_size(bag) / MB, 1) if ros2 else None,
        "bag_messages": _bag_messages(bag) if ros2 else None,
        "bag_files_readable_alone": all(_readable_alone(part) > 0 for part in bag.glob("*.mcap")) if ros2 else None,
        "rotated": report["rotated"],
        "report_again": {
            "exit_code": again.returncode,
            "covers": [line for line in again.stdout.splitlines() if "covers" in line],
        },
        "last_lines": (("".join(lines) + rest).splitlines())[-12:],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--sim-hours", type=float, default=3.0, help="simulation time to run (default 3 h)")
    parser.add_argument("--sample-every", type=float, default=5.0, help="seconds between journal sizes")
    parser.add_argument("--no-ros2", action="store_true", help="no --record-ros2")
    parser.add_argument("--goals", action="store_true", help="--goals --mode lockstep instead of --loop")
    parser.add_argument(
        "--up", action="append", default=[], metavar="ARG", help="one more argument of invent up (--up=--composed)"
    )
    parser.add_argument(
        "--keep", metavar="DIR", help="leave the run's report directory here (default: a temporary one)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temporary:
        report_dir = Path(args.keep) if args.keep else Path(temporary) / "run"
        commander = ["--goals", "--mode", "lockstep"] if args.goals else ["--loop"]
        result = soak(args.sim_hours, args.sample_every, not args.no_ros2, report_dir, commander, args.up)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    fine = result["exit_code"] == 0 and result["each_file_readable_alone"] and result["report_again"]["exit_code"] == 0
    return 0 if fine else 1


if __name__ == "__main__":
    sys.exit(main())
