"""``invent calibrate umbmark``: the odometry's calibration (services/launch/calibrate.py)."""

from __future__ import annotations

import argparse

from services.cli.flags import description_flags
from services.cli.services import service_plan
from services.cli.subcommand import Subcommand
from services.launch import calibrate


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
    calibrate.add_arguments(umbmark)
    umbmark.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    # services/launch/calibrate.py still names what it hands its composition an ArgumentParser;
    # h6-calib's version of it, which the lead merges, takes the service parse it is now.
    return calibrate.run_umbmark(args, service_plan)  # type: ignore[arg-type]


SUBCOMMAND = Subcommand(
    name="calibrate",
    help="calibrate the odometry: UMBmark, in the simulator or from return positions measured by hand",
    description="Calibrate the robot's odometry. The one method: umbmark (`invent calibrate umbmark --help`).",
    groups=(),
    add_arguments=add_arguments,
    run=run,
)
