"""``invent report``: report.json and the plots rebuilt from the recording of a run (run.mcap)."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.cli.flags import config_from_args, existing_file
from services.recording.report import summary
from services.recording.run_report import write_run_report


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
    "recording's directory). --robot and --config must match the run's. Any run's recording is "
    "reported, cut short or not (a file cut mid-chunk, a run with no summary): the report and "
    "its `missing:` lines say what it lacks. Exit 2 only for a file that is not a recording, or "
    "that holds other robots' keys but none of --robot's."
)
GROUPS: tuple[str, ...] = ("description",)
