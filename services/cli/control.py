"""``invent control``: the control path, the sim and the motor, composed in one process.

Every step of the loop crosses between the sim and the motor twice (the wheel angles out, the
torque back). As two processes, each crossing wakes a thread in the other and, through a router
(a secure deployment, docker compose), twice more in the router. Composed on one session, as
``invent up --composed`` composes the whole loop, the two hand each other their messages in the
process (services/launch/composition.py) and only the observers' copies go out over zenoh: under
docker compose on the 2-CPU VM, no late step in 45,002 (three runs, and an hour) against 4.1-6.4 %
as two containers (benchmarks/README.md, "Compose"). The other services (odometry, localization, the drive, the
ROS 2 bridge, the view) keep their own processes. One robot's: a fleet's sim is the fleet's.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from schemas.keys import Service
from schemas.status import ComposedServices, ControlStatus, MotorStatus, SimStatus
from services.cli.flags import session_from_args
from services.cli.serve import add_journal_arguments, plan_from_args
from services.cli.services import service_cli
from services.config import SIM_BODY_KEYS, ConfigError, parse_sim_set
from services.launch.composition import Composition, run_composed
from services.runtime.realtime import apply_realtime
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals
from services.service import ServicePlan

COMPOSED = (Service.MOTOR, Service.SIM)
"""Started in this order: the sim's thread runs the loop and handles the motor's inputs."""


def control_status(robot: str, uptime_s: float, sim: SimStatus, motor: MotorStatus) -> ControlStatus:
    """The process's own status (``control/status``): the motor's state, the sim's steps and late
    fraction and both services' internal errors first, as a container's health check reads them,
    then each service's whole status under its name (the same as ``sim/status`` and ``motor/status``)."""
    return ControlStatus(
        service="control",
        robot=robot,
        uptime_s=round(uptime_s, 3),
        state=motor.state,
        steps=sim.steps,
        late_fraction=sim.late_fraction,
        internal_errors=sim.internal_errors + motor.internal_errors,
        services=ComposedServices(sim=sim, motor=motor),
    )


def serve_status(composition: Composition) -> None:
    """Answer ``control/status`` from the composition's thread, where both services' own run."""
    node = composition.services[-1].node
    since = time.monotonic()

    def status(_payload: bytes) -> ControlStatus:
        services = {composed.name: composed.node.status() for composed in composition.services}
        sim, motor = services[Service.SIM], services[Service.MOTOR]
        assert isinstance(sim, SimStatus) and isinstance(motor, MotorStatus), "the composition is the sim and the motor"
        return control_status(node.keys.robot, time.monotonic() - since, sim, motor)

    node.declared.also_serve(node.keys.control_status)
    node.queryable(node.keys.control_status, status)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    for name in COMPOSED:
        service_cli(name).add_arguments(parser)
    add_journal_arguments(parser)  # both services' journals go there
    parser.add_argument(
        "--sim-set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        help="the sim's description alone differs from the motor's by this (repeatable, after every --set): the "
        "simulated body and its sensors' noise (invent up --sim-set). Keys: " + ", ".join(SIM_BODY_KEYS),
    )


def composed_plans(args: argparse.Namespace) -> list[tuple[str, ServicePlan[Any]]]:
    """The motor's and the sim's plans, in :data:`COMPOSED`'s order: the sim's description is the
    motor's with ``--sim-set`` after every ``--set`` (the later value of a key wins); ConfigError
    naming a ``--sim-set`` key that is not of the simulated body."""
    parse_sim_set(args.sim_set or ())
    # --mode is the run's: the motor's publishers too meet congestion as the mode says (protocol §2.6)
    mode = [f"sim.mode={args.mode}"] if args.mode else []
    motor_args = argparse.Namespace(**{**vars(args), "set": [*(args.set or ()), *mode]})
    sim_args = argparse.Namespace(**{**vars(args), "set": [*(args.set or ()), *(args.sim_set or ())]})
    return [
        (name, plan_from_args(service_cli(name), sim_args if name == Service.SIM else motor_args)) for name in COMPOSED
    ]


def run(args: argparse.Namespace) -> int:
    if args.fleet:
        raise ConfigError(
            "invent control --fleet: a fleet's simulator is the fleet's and each robot's motor its own; "
            "compose a fleet with invent up --fleet FILE --composed, or run invent sim --fleet and the motors apart"
        )
    plans = composed_plans(args)
    rt = plans[-1][1].config.rt
    # With --rt, the loop's thread alone goes on rt.cpus (pin_loop_thread), as in invent up --composed;
    # without, rt.partition puts the whole process there, the control path's CPU.
    apply_realtime(rt, "invent control", control_path=True, composed=rt.enabled)
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args)) as session:
        return run_composed(session, plans, stop, serve_status)


HELP = "the control path, the sim and the motor, composed in one process (no network hop between them)"
DESCRIPTION = (
    "Runs invent sim and invent motor in one process on one zenoh session, as invent up --composed runs the "
    "whole loop: each step's wheel angles and torque are handed over in the process, and only what others "
    "subscribe to goes out over zenoh, under the same keys (sim/*, motor/*) and queryables (sim/status, "
    "motor/status, motor/gui/*, motor/bump/*) as the two processes serve, and its own status on control/status "
    "(the motor's state, the sim's steps and late fraction, then both statuses). Takes the flags of both. For a "
    "deployment that runs each other service apart, over a router: docker compose's control container "
    "(docs/deploy.md); with --zenoh-config, the control role's credentials (docs/security.md). "
    "Ends when signalled, or when either ends by itself (the sim after --duration), with that one's exit status."
)
GROUPS: tuple[str, ...] = ("connection", "description", "rt")
