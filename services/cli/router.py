"""``invent router``: a zenoh router in Python (no zenohd needed)."""

from __future__ import annotations

import argparse
import json

from services.cli import tools
from services.cli.flags import session_from_args
from services.config import ConfigError, load_config, parse_override
from services.runtime.realtime import apply_realtime
from services.runtime.session import DEFAULT_ENDPOINT, SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", dest="zenoh_config", metavar="FILE", help="zenoh router configuration file")
    parser.add_argument(
        "--set",
        metavar="rt.KEY=VALUE",
        action="append",
        help="a real-time setting of the robot description's [rt] table, e.g. --set rt.priority=70 (repeatable)",
    )


def run(args: argparse.Namespace) -> int:
    overrides = dict(map(parse_override, args.set or ()))
    not_rt = [key for key in overrides if not key.startswith("rt.")]
    if not_rt:
        raise ConfigError(f"invent router --set {', '.join(not_rt)}: a router takes only the [rt] settings")
    apply_realtime(
        load_config(overrides={**overrides, "rt.enabled": args.rt or None}).rt, "invent router", control_path=True
    )
    config = session_from_args(args, mode="router")
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(config) as session:
        return tools.run_router(session, json.loads(config.get_json("listen/endpoints")), stop)


HELP = "run a zenoh router in Python (no zenohd needed)"
DESCRIPTION = (
    f"A zenoh router; services connect to it. Default listen: {DEFAULT_ENDPOINT}. "
    "--config FILE (or $ZENOH_CONFIG) takes a zenoh router configuration, such as the router.json5 of "
    "`invent secrets` (authentication and access control)."
)
GROUPS: tuple[str, ...] = ("connection", "rt")
