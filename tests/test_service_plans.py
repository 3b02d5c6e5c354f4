"""A service's plan rendered as its command line (services/launch/service_plans.py) and parsed back by
``invent``'s own parser is the same plan: the command line a run gives a child and the plan it
composes from cannot drift apart. For every built-in service and its options, its robot
description, journal and connection; ``invent control``'s and a worker's plans too. Pure: no zenoh."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.keys import Service, user_service_name
from services.cli.control import composed_plans
from services.cli.flags import connection_from_args
from services.cli.main import build_parser
from services.cli.services import service_plan
from services.drive.options import DriveOptions, goal_options, scenario_options
from services.drive.scenarios import BUILTIN_SCENARIOS, ConstantSegment, Scenario, WaypointSegment
from services.drive.service import TWIST_PASS_S
from services.launch.plan import Connection, Description
from services.launch.service_plans import (
    BUILT_IN,
    ChildPlan,
    ControlPlan,
    decode_plan,
    encode_plan,
    service_argv,
    sim_options,
)
from services.motor.service import MotorOptions
from services.odometry.service import OdometryOptions
from services.ros2.service import Ros2Options
from services.service import Journaling, NoOptions

REPO = Path(__file__).resolve().parent.parent
SETTINGS = (
    "motor.p_gain_l=3.5",
    "drive.rate=25.0",
    "sim.mode=realtime",
    "sim.step=0.002",
    "lidar.noise=0.01",
    "localization.seed=7",
    "localization.noise_x=0.05",
    "rt.priority=70",
    'ros2.tf="prefixed"',
    'robot.name="rh3"',
    "navigation.enabled=false",
)
"""Settings of every section a service's flags set (each flag that sets a key is rendered as its ``--set``)."""

numbers = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
seconds = st.floats(min_value=1e-6, max_value=1e6, allow_nan=False, allow_infinity=False)
paths = st.sampled_from(["trace.jsonl", "runs/a b/state.json", "/tmp/x-1"])
descriptions = st.builds(
    Description,
    robot=st.none() | st.sampled_from(["rh0", "rh7"]),
    config=st.none(),
    settings=st.lists(st.sampled_from(SETTINGS), max_size=4).map(tuple),
    rt=st.booleans(),
)
journals = st.builds(
    Journaling, directory=st.none() | st.sampled_from([Path("journals"), Path("/tmp/run 1")]), share=st.integers(1, 9)
)
connections = st.builds(
    Connection,
    connect=st.lists(st.sampled_from(["tcp/127.0.0.1:7447", "tcp/[::1]:1"]), max_size=2).map(tuple),
    listen=st.lists(st.just("tcp/0.0.0.0:0"), max_size=1).map(tuple),
    zenoh_config=st.none() | st.just("secrets/motor.json5"),
    log_level=st.sampled_from(["debug", "info", "warning"]),
)


def _drive(mode: str, segment: Any, loop: bool) -> DriveOptions:
    return DriveOptions(mode, Scenario(name=mode, segments=[segment]), loop)


drive_options = st.one_of(
    st.builds(
        scenario_options, st.sampled_from([*BUILTIN_SCENARIOS, "examples/scenarios/forward.toml"]), st.booleans()
    ),
    st.builds(goal_options, st.none() | st.sampled_from(["examples/goals/u_trap.toml", "examples/goals/errands.toml"])),
    st.builds(
        _drive, st.just("constant"), st.builds(ConstantSegment, vx=numbers, w=numbers, duration=seconds), st.booleans()
    ),
    st.builds(
        _drive,
        st.just("twist"),
        st.builds(ConstantSegment, vx=numbers, w=numbers, duration=st.just(TWIST_PASS_S)),
        st.just(True),
    ),
    st.builds(
        _drive,
        st.just("waypoints"),
        st.builds(WaypointSegment, waypoints=st.lists(st.tuples(numbers, numbers), min_size=1, max_size=4)),
        st.booleans(),
    ),
)
waited = st.lists(
    st.sampled_from([Service.MOTOR, Service.DRIVE, Service.LOCALIZATION, user_service_name("wander")]),
    unique=True,
    max_size=3,
).map(tuple)
OPTIONS: dict[str, st.SearchStrategy[Any]] = {
    "motor": st.builds(MotorOptions, trace=st.none() | paths, state=st.none() | paths.map(Path)),
    "odometry": st.builds(OdometryOptions, trace=st.none() | paths),
    "localization": st.just(NoOptions()),
    "drive": drive_options,
    "ros2": st.builds(Ros2Options, bag_journal=st.none() | paths.map(Path), bag_journal_share=st.integers(1, 9)),
}


def _sim(description: Description, draw: st.DrawFn) -> Any:
    return sim_options(
        description,
        draw(st.none() | st.sampled_from(["examples/fleets/two_squares.toml", "examples/fleets/corridor_swap.toml"])),
        duration=draw(st.none() | seconds),
        until_drive_ends=draw(st.booleans()),
        wait_for=draw(waited),
        gui=draw(st.booleans()) and "sim.engine=kinematic" not in description.settings,
    )


@st.composite
def child_plans(draw: st.DrawFn, service: str) -> ChildPlan[Any]:
    description = draw(descriptions)
    command, _ = BUILT_IN[service]
    options = _sim(description, draw) if service == "sim" else draw(OPTIONS[service])
    return ChildPlan(f"rh0/{service}", command, options, description, draw(journals), draw(connections))


@pytest.fixture(autouse=True)
def _in_the_repo(monkeypatch):
    monkeypatch.chdir(REPO)  # the examples' relative paths, as invent up is run


@pytest.mark.parametrize("service", list(BUILT_IN))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_plan_rendered_and_parsed_back_is_the_same_plan(service: str, data: st.DataObject) -> None:
    child = data.draw(child_plans(service))
    argv = service_argv(child)
    assert argv[0] == service
    assert service_plan(argv) == child.service_plan(), argv
    assert connection_from_args(build_parser(service).parse_args(argv)) == child.connection


@pytest.mark.parametrize("service", ["motor", "odometry", "localization", "drive", "ros2"])
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_a_worker_is_sent_a_plan_it_decodes_as_it_was(service: str, data: st.DataObject) -> None:
    child = data.draw(child_plans(service))
    decoded = decode_plan(encode_plan(child))
    assert decoded == ChildPlan(child.name, child.command, child.options, child.description, child.journaling)


def test_numbers_that_look_like_flags_are_rendered_as_values() -> None:
    twist = _drive("twist", ConstantSegment(vx=-1e-05, w=-2.5e20, duration=TWIST_PASS_S), True)
    child = ChildPlan("drive", BUILT_IN["drive"][0], twist)
    argv = service_argv(child)
    assert argv[argv.index("--twist") :] == ["--twist", "-0.00001", "-250000000000000000000"]
    assert service_plan(service_argv(child)).options == twist


def test_the_control_child_composes_the_motor_and_the_sim_its_plan_says() -> None:
    description = Description("rh0", None, ("sim.mode=realtime", "motor.p_gain_l=4.0"), rt=True)
    motor = ChildPlan(
        "control",
        BUILT_IN["motor"][0],
        MotorOptions(state=Path("runs/x/motor-state.json")),
        description,
        Journaling(Path("runs/x/journals"), 7),
        Connection(("tcp/127.0.0.1:7447",), zenoh_config="secrets/control.json5"),
    )
    simulation = sim_options(description, until_drive_ends=True, wait_for=(Service.DRIVE, Service.LOCALIZATION))
    control = ControlPlan(motor, simulation, ("lidar.noise=0.02",))
    argv = service_argv(control)
    assert argv[0] == "control"
    sim = ChildPlan(
        "sim",
        BUILT_IN["sim"][0],
        simulation,
        Description("rh0", None, (*description.settings, "lidar.noise=0.02"), rt=True),
        motor.journaling,
    )
    args = build_parser("control").parse_args(argv)
    assert composed_plans(args) == [("motor", motor.service_plan()), ("sim", sim.service_plan())]
    assert connection_from_args(args) == motor.connection
