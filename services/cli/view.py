"""``invent view``: the running robot live in Foxglove (a Foxglove WebSocket server)."""

from __future__ import annotations

import argparse

from schemas.keys import Keys
from services.cli.flags import config_from_args, fleet_flag, overrides_from_args, port_number, session_from_args
from services.fleet.description import fleet_configs, load_fleet
from services.recording import view
from services.runtime.realtime import apply_realtime
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        type=port_number,
        default=view.DEFAULT_PORT,
        metavar="PORT",
        help=f"TCP port to serve on (default {view.DEFAULT_PORT}; 0: any free port, which it prints)",
    )
    parser.add_argument(
        "--host",
        default=view.DEFAULT_HOST,
        metavar="ADDR",
        help=f"address to serve on (default {view.DEFAULT_HOST}, this machine only; 0.0.0.0 for every "
        "interface, e.g. in a container)",
    )
    fleet_flag(
        parser,
        "show every robot of this fleet file: each robot's frame <robot>/base_link, its poses and wheel "
        "speeds under /<robot>/..., its body, path and trails in /scene (docs/fleet.md)",
    )


def run(args: argparse.Namespace) -> int:
    config = config_from_args(None, args)
    fleet = (
        tuple(fleet_configs(load_fleet(args.fleet), args.config, overrides_from_args(None, args)).values())
        if args.fleet
        else ()
    )
    apply_realtime(config.rt, "invent view", control_path=False)
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args)) as session:
        return view.run_view(
            session, Keys(config.robot.name), config, stop, host=args.host, port=args.port, fleet=fleet
        )


HELP = "show the running robot live in Foxglove (a Foxglove WebSocket server)"
DESCRIPTION = (
    "Serve the robot's loop live to Foxglove over a Foxglove WebSocket server: every key of "
    "invent/<robot>/** as its own JSON channel (with its message type's JSON schema), the services' status "
    "every 0.5 s (the motor's state, the sim's torque counters), and the robot's Foxglove scene: /tf "
    "(world -> base_link, the ground truth), /odometry/pose and /localization/pose, /scene (the robot, the "
    "world's obstacles, the planned path, the trails, a goal-mode drive's goals and the path driven to each) and /plot/wheel_speeds, the channels a recording holds. "
    "Open it in Foxglove: Open connection -> Foxglove WebSocket -> ws://HOST:PORT (the URL it prints), then "
    "Layouts -> Import from file -> docs/foxglove/layout.json for a 3D view, wheel speeds, torques, a goal's "
    "progress and the motor's and the goal's states. Runs until Ctrl-C or SIGTERM."
)
GROUPS: tuple[str, ...] = ("connection", "description")
