"""``invent report``: report.json and the plots rebuilt from the recording of a run (run.mcap)."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.cli.flags import config_from_args, existing_file
from services.recording.mcap_files import write_run_report
from services.recording.report import summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="FILE.mcap", help="the recording, e.g. runs/<timestamp>/run.mcap")
    parser.add_argument("--output-dir", metavar="DIR", help="where to write (default: beside the recording)")


def run(args: argparse.Namespace) -> int:
    path = existing_file(args.recording)
    report, report_path, plots = write_run_report(
        path, Path(args.output_dir) if args.output_dir else path.parent, config_from_args(None, args)
    )
    print(summary(report))
    print(f"report: {report_path}; plots: {', '.join(str(p) for p in plots)}")
    return 0


HELP = "rebuild report.json and the plots from the recording of a run (run.mcap)"
DESCRIPTION = (
    "Read a recording of `invent up` (its run.mcap) and write report.json, trajectory.png and "
    "wheel_speeds.png, as `invent up` does at the end of a run, into --output-dir (default: the "
    "recording's directory). --robot and --config must match the run's."
)
GROUPS: tuple[str, ...] = ("description",)
