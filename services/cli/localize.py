"""``invent localize X Y THETA``: tell the robot's localization where the robot is, about
(``localization/initial_pose``, ROS's ``/initialpose``, RViz's "2D Pose Estimate"), or with
``--global`` have it spread its particles over the whole map (``localization/global_localization``),
and print its reply. Only ``localization.mode = "amcl"`` serves these queryables: the stub reads the
simulator's pose and ``none`` takes no fix, so nothing answers them there, and the tool says so.

Exit statuses as ``invent goto``'s for a request: 0 accepted, 1 refused (the reason printed) or
nothing answered within ``--wait`` (the key named), 2 bad arguments."""

from __future__ import annotations

import argparse
import sys
from functools import partial

import zenoh

from schemas.keys import DEFAULT_ROBOT, Keys, Service
from schemas.messages import NoArguments
from schemas.navigation import InitialPose, LocalizationReply
from services.cli.flags import finite_number, non_negative_float, positive_seconds, robot_name, session_from_args
from services.cli.tools import ask
from services.exits import ExitStatus
from services.runtime.session import open_session

DEFAULT_WAIT_S = 5.0
"""Wall seconds the tool waits for the localization to answer (``--wait``)."""
ALIVE_LOOK_S = 1.0
"""Wall seconds the tool asks, when nothing answered, whether the localization runs at all."""


def covariance(sigma_xy: float | None, sigma_theta: float | None) -> list[float]:
    """The covariance sent for ``--sigma-xy`` and ``--sigma-theta``: the upper triangle of
    diag(σxy², σxy², σθ²), row by row (xx, xy, xθ, yy, yθ, θθ); none given: ``[]`` (the
    localization's own ``amcl.initial_sigma_xy`` and ``amcl.initial_sigma_theta``)."""
    if sigma_xy is None and sigma_theta is None:
        return []
    if sigma_xy is None or sigma_theta is None:
        raise ValueError(
            "give both --sigma-xy and --sigma-theta, or neither (the localization's own amcl.initial_sigma_*)"
        )
    xx, tt = sigma_xy**2, sigma_theta**2
    return [xx, 0.0, 0.0, xx, 0.0, tt]


def initial_pose(x: float, y: float, theta: float, sigma_xy: float | None, sigma_theta: float | None) -> InitialPose:
    """The ``localization/initial_pose`` payload of the command's arguments (ValueError: a sigma alone)."""
    return InitialPose(x=x, y=y, theta=theta, covariance=covariance(sigma_xy, sigma_theta))


def _pose_text(pose: InitialPose) -> str:
    spread = (
        f"sigma xy {pose.covariance[0] ** 0.5:.3f} m, sigma theta {pose.covariance[5] ** 0.5:.3f} rad"
        if pose.covariance
        else "the localization's own spread"
    )
    return f"x {pose.x:+.3f} y {pose.y:+.3f} theta {pose.theta:+.3f} ({spread})"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("x", type=finite_number, nargs="?", metavar="X", help="where the robot is: x in map (m)")
    parser.add_argument("y", type=finite_number, nargs="?", metavar="Y", help="where the robot is: y in map (m)")
    parser.add_argument(
        "theta", type=finite_number, nargs="?", metavar="THETA", help="where the robot faces in map (rad)"
    )
    parser.add_argument(
        "--sigma-xy",
        type=non_negative_float,
        metavar="M",
        help="the pose's standard deviation in x and in y (m); with --sigma-theta (both or neither; default: the "
        "localization's amcl.initial_sigma_xy)",
    )
    parser.add_argument(
        "--sigma-theta",
        type=non_negative_float,
        metavar="RAD",
        help="the heading's standard deviation (rad); with --sigma-xy (default: the localization's "
        "amcl.initial_sigma_theta)",
    )
    parser.add_argument(
        "--global",
        dest="global_localization",
        action="store_true",
        help="no X Y THETA: the robot could be anywhere; the localization spreads its particles over the map's "
        "free space (localization/global_localization)",
    )
    parser.add_argument(
        "--robot", type=robot_name, default=DEFAULT_ROBOT, metavar="NAME", help=f"the robot (default {DEFAULT_ROBOT})"
    )
    parser.add_argument(
        "--wait",
        type=positive_seconds,
        default=DEFAULT_WAIT_S,
        metavar="S",
        help=f"wall seconds to wait for the localization to answer (default {DEFAULT_WAIT_S:g}); then exit 1 "
        "naming the key",
    )


def _error(line: str) -> None:
    print(f"invent localize: {line}", file=sys.stderr, flush=True)


def _request(args: argparse.Namespace) -> InitialPose | NoArguments | str:
    """What to send, or why the arguments do not say (a usage error)."""
    given = [value for value in (args.x, args.y, args.theta) if value is not None]
    if args.global_localization:
        if given or args.sigma_xy is not None or args.sigma_theta is not None:
            return "--global takes no X Y THETA and no --sigma-xy or --sigma-theta"
        return NoArguments()
    if len(given) != 3:
        return "give X Y THETA (where the robot is), or --global"
    try:
        return initial_pose(args.x, args.y, args.theta, args.sigma_xy, args.sigma_theta)
    except ValueError as error:
        return str(error)


def run(args: argparse.Namespace) -> int:
    request = _request(args)
    if isinstance(request, str):
        _error(request)
        return ExitStatus.CONFIG
    keys = Keys(args.robot)
    key = keys.localization_initial_pose if isinstance(request, InitialPose) else keys.localization_global_localization
    # Client mode, as the one-shot tools (docs/protocol.md section 11.4).
    with open_session(session_from_args(args, mode="client")) as session:
        reply = ask(session, key, request, LocalizationReply, args.wait, _error, partial(_hint, session, keys))
    if not isinstance(reply, LocalizationReply):
        return reply
    what = f"initial pose {_pose_text(request)}" if isinstance(request, InitialPose) else "global localization"
    if not reply.accepted:
        _error(f"{keys.robot}'s localization refused the {what}: {reply.reason or 'no reason given'}")
        return ExitStatus.FAILURE
    print(f"{what} accepted by {keys.robot}'s localization", flush=True)
    return ExitStatus.OK


def _hint(session: zenoh.Session, keys: Keys, matched: bool) -> str:
    """Why nothing may have answered: the localization not running, or not in amcl mode, or the ACL."""
    if matched:
        return (
            "; in a secure deployment only the operator and the ROS 2 bridge may query it (the router drops the "
            "others' unanswered)"
        )
    replies = session.liveliness().get(keys.alive(Service.LOCALIZATION), timeout=ALIVE_LOOK_S)
    if any(reply.ok is not None for reply in replies):
        return (
            f'; {keys.robot}\'s localization is running but does not serve it: only localization.mode = "amcl" '
            "does (`invent up --map FILE --set localization.mode=amcl`); the stub and none take no pose"
        )
    return (
        f"; no localization of {keys.robot} is running (its token {keys.alive(Service.LOCALIZATION)} is not there); "
        'start one with localization.mode = "amcl"'
    )


HELP = "tell the localization where the robot is (amcl's initial pose), or --global: anywhere on the map"
DESCRIPTION = (
    "Send the robot's localization an initial pose (localization/initial_pose; ROS's /initialpose, RViz's "
    '"2D Pose Estimate"): the robot is about at (X, Y) in map facing THETA (rad), with the standard deviations '
    "--sigma-xy (m) and --sigma-theta (rad) (both or neither; neither: the localization's own "
    "amcl.initial_sigma_xy and amcl.initial_sigma_theta), and the particle filter is seeded again around it. "
    "With --global (and no X Y THETA), the robot could be anywhere: the particles are spread over the map's free "
    "space (localization/global_localization). Prints the localization's reply; exits 0 accepted, 1 refused "
    "(its reason printed, as `invent goto` for a rejected goal) or nothing answering within --wait (the key "
    'named: only localization.mode = "amcl" serves these, not the stub nor none), 2 bad arguments (a number '
    "not finite, a sigma alone, X Y THETA with --global). In a secure deployment, connect as the operator "
    "(--zenoh-config operator.json5): the observer may not send it."
)
GROUPS: tuple[str, ...] = ("connection",)
