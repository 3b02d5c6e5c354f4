"""``invent calibrate umbmark``'s flags, and its run: the flags turned into typed settings
(``services/calibration/settings.py``) here, at the edge, then ``services/launch/calibrate.py``."""

from __future__ import annotations

import argparse
from pathlib import Path

from services.calibration.settings import DEFAULT_PASSES, UmbmarkSettings
from services.calibration.umbmark import CONVERGED, DEFAULT_RUNS, DEFAULT_SIDE
from services.cli.flags import description_flags, overrides_from_args, positive_int, positive_length
from services.config import (
    SIM_BODY_KEYS,
    ConfigError,
    config_from_description,
    parse_sim_set,
    read_description,
)
from services.launch.calibrate import run_umbmark
from services.launch.run import default_report_dir
from services.recording.calibration_report import FIGURE_FILE, RECORDING_FILE, REPORT_FILE
from services.runtime.logs import LOG_LEVELS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    methods = parser.add_subparsers(dest="method", required=True, metavar="METHOD")
    umbmark = methods.add_parser(
        "umbmark",
        parents=[description_flags()],
        help="UMBmark: drive a square both ways on odometry alone, correct the wheel radii and the wheelbase",
        description="UMBmark (Borenstein and Feng 1996): drive a square of side --side clockwise and "
        "counter-clockwise --runs times each on odometry alone, take where the robot really stops, and compute the "
        "systematic errors Ed (the ratio of the wheel diameters) and Eb (the wheelbase's) and the corrected "
        "odometry.left_radius_scale, right_radius_scale and axle_scale (used by the odometry and by the motor's "
        "wheel-speed conversion alike). In the simulator (the default) the loop runs composed in lockstep with no "
        "localization, the simulated body changed by --sim-set only, and the benchmark runs again with the "
        "corrections applied (E_max,syst before and after). --measured FILE takes return positions measured with a "
        "tape on the real robot instead. Writes report.json, umbmark.png (the paper's figure) and umbmark.mcap (the "
        "runs' paths, for Foxglove) into --report DIR, and with -o FILE the robot description with the corrections. "
        "Exit 0 done, 1 a run failed, 2 bad arguments or configuration, 130 Ctrl-C. See docs/odometry.md.",
    )
    umbmark_arguments(umbmark)
    umbmark.set_defaults(handler=run)


def umbmark_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--side",
        type=positive_length,
        metavar="M",
        help=f"the square's side in metres (default {DEFAULT_SIDE:g}, the paper's; with --measured, the file's if it "
        "gives one)",
    )
    parser.add_argument(
        "--runs",
        type=positive_int,
        metavar="N",
        help=f"runs in each direction per benchmark (default {DEFAULT_RUNS}, the paper's); in lockstep the runs of "
        "one direction end at the same place",
    )
    parser.add_argument(
        "--passes",
        type=positive_int,
        metavar="N",
        help=f"at most N corrections (default {DEFAULT_PASSES}), each followed by the benchmark with it applied; a "
        f"further one only while the correction that benchmark gives would change a multiplier by {CONVERGED * 100:g} %% "
        "or more (the paper's first-order formulas leave a few per cent of large errors)",
    )
    parser.add_argument(
        "--sim-set",
        metavar="KEY=VALUE",
        action="append",
        help="the simulated body differs from the description by this (repeatable), e.g. "
        "--sim-set robot.radius_of_right_wheel=0.1005 --sim-set robot.length_of_axle=0.45: the 'true' robot; "
        "every other service keeps the description. Keys: " + ", ".join(SIM_BODY_KEYS),
    )
    parser.add_argument(
        "--measured",
        metavar="FILE",
        help="no simulator: the return positions measured by hand on the robot, a TOML or CSV file "
        "(docs/odometry.md, Measuring by hand)",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="FILE",
        help="write the robot description given (--config, --set) with the corrected odometry.*_scale: run the "
        "robot with --config FILE",
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help=f"where {REPORT_FILE}, {FIGURE_FILE} (the paper's figure) and {RECORDING_FILE} (the runs' paths, "
        "for Foxglove) go (default runs/<timestamp>/)",
    )
    parser.add_argument(
        "--listen",
        metavar="EP",
        help="where each run's session (a router, as invent up --composed's) listens, e.g. to watch a run with "
        "invent view --connect EP (default a free port on 127.0.0.1)",
    )
    parser.add_argument(
        "--log-level",
        default="warning",
        choices=LOG_LEVELS,
        help="the services' log level (default warning: the calibration's own lines only)",
    )


def settings_from_args(args: argparse.Namespace) -> UmbmarkSettings:
    """The flags as typed settings; ConfigError naming the flag (or the description's field) that
    cannot be taken."""
    if args.measured:
        given = [
            flag
            for flag, value in (("--runs", args.runs), ("--passes", args.passes), ("--sim-set", args.sim_set))
            if value
        ]
        if given:
            raise ConfigError(f"{', '.join(given)}: --measured computes from a file, with no simulator to run")
    sim_set = parse_sim_set(args.sim_set or ())
    output = Path(args.output) if args.output else None
    if output is not None and not output.parent.is_dir():
        raise ConfigError(f"-o {output}: no directory {output.parent} to write it in")
    description = read_description(args.config, overrides_from_args(None, args))
    return UmbmarkSettings(
        side=args.side or DEFAULT_SIDE,
        side_given=args.side is not None,
        runs=args.runs or DEFAULT_RUNS,
        passes=args.passes or DEFAULT_PASSES,
        sim_set=sim_set,
        measured=Path(args.measured) if args.measured else None,
        description=description,
        config=config_from_description(description),
        report_dir=Path(args.report) if args.report else default_report_dir(),
        output=output,
        config_file=Path(args.config) if args.config else None,
        robot=args.robot,
        sets=tuple(args.set or ()),
        log_level=args.log_level,
        listen=args.listen,
    )


def run(args: argparse.Namespace) -> int:
    return run_umbmark(settings_from_args(args))


HELP = "calibrate the odometry: UMBmark, in the simulator or from return positions measured by hand"
DESCRIPTION = "Calibrate the robot's odometry. The one method: umbmark (`invent calibrate umbmark --help`)."
GROUPS: tuple[str, ...] = ()
