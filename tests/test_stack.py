"""``invent up --print-stack`` and ``--stack FILE`` (services/launch/stack.py, docs/stack.md): a run
as a typed description. The flags' run and its printed stack's are one run: the same plan here for
every kind of run, the same report for whole runs (tests/test_stack_runs.py); a stack that cannot
be run exits 2 naming why."""

from __future__ import annotations

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.cli.main import build_parser
from services.cli.up import plan_from_args
from services.exits import ExitStatus
from services.launch.stack import Goals, Scenario, Stack, plan_from_stack, read_stack, stack_from_plan, stack_toml
from tests.harness import REPO, refused

FLAG_SETS = {
    "default": [],
    "fleet": ["--fleet", str(REPO / "examples/fleets/two_squares.toml"), "--composed", "--workers", "2"],
    "goals": ["--goals", "--ros2", "--record-ros2", "--restart", "on-failure", "--restart", "drive=never"],
    "goal file": ["--goal-file", str(REPO / "examples/goals/u_trap.toml"), "--mode", "lockstep", "--strict"],
    "teleop": ["--teleop", "--ros2", "--tf", "prefixed", "--secure", "--tls", "--report", "runs/t"],
    "loop": ["--scenario", "figure8", "--loop", "--no-record", "--view", "9000", "--engine", "kinematic"],
    "split": ["--mode", "realtime", "--split", "--rt", "--set", "lidar.noise=0.01", "--sim-set", "lidar.noise=0.02"],
    "composed": ["--composed", "--no-intra-process", "--robot", "rh7", "--connect", "tcp/127.0.0.1:7448"],
    "own services": ["--composed", "--with", "examples/services/fix_ledger.py:FixLedger", "--restart", "on-failure"],
    "record": ["--record-full-rate", "--restart-limit", "3", "--restart-backoff", "0.5", "--log-level", "debug"],
}


def _plan(flags: list[str]):
    return plan_from_args(build_parser("up").parse_args(["up", *flags]))


@pytest.mark.parametrize("flags", FLAG_SETS.values(), ids=FLAG_SETS.keys())
def test_the_printed_stack_of_the_flags_reads_back_as_the_run_the_flags_give(tmp_path, capsys, flags):
    code, out, err = refused(capsys, "up", *flags, "--print-stack")
    assert code == ExitStatus.OK, err
    stack_file = tmp_path / "s.toml"
    stack_file.write_text(out)
    assert plan_from_stack(read_stack(str(stack_file))) == _plan(flags)
    code, again, err = refused(capsys, "up", "--stack", str(stack_file), "--print-stack")
    assert (code, again) == (ExitStatus.OK, out), err


@given(
    commander=st.sampled_from([Scenario(), Scenario(name="square", loop=True), Goals(), Goals(file="g.toml")]),
    settings=st.lists(st.sampled_from(["lidar.noise=0.01", 'robot.name="x"', "sim.step=0.002"]), max_size=3),
    strict=st.booleans(),
    view=st.one_of(st.none(), st.integers(1, 65535)),
)
def test_every_stack_printed_reads_back_as_itself_through_its_plan(tmp_path_factory, commander, settings, strict, view):
    stack = msgspec.structs.replace(
        Stack(),
        commander=commander,
        strict=strict,
        observers=msgspec.structs.replace(Stack().observers, view=view),
        description=msgspec.structs.replace(Stack().description, settings=settings),
    )
    path = tmp_path_factory.mktemp("stack") / "s.toml"
    path.write_text(stack_toml(stack))
    assert read_stack(str(path)) == stack
    assert stack_from_plan(plan_from_stack(stack)) == stack


INVALID = {
    "an unknown key": ("wheels = 3\n", "unknown field `wheels`"),
    "an unknown commander": ('[commander]\nkind = "dance"\n', "commander.kind: Invalid value 'dance' (kind is one of"),
    "a composed run split": (
        '[processes]\nkind = "composed"\nsplit = true\n',
        "processes: Object contains unknown field `split`",
    ),
    "goals that loop": (
        '[commander]\nkind = "goals"\nloop = true\n',
        "commander: Object contains unknown field `loop`",
    ),
    "a bag without the bridge": (
        '[recording]\nkind = "record"\nros2_bag = true\n',
        "recording: Object contains unknown field",
    ),
    "workers as words": (
        '[processes]\nkind = "composed"\nworkers = "two"\n',
        "processes.workers: Expected `int | null`",
    ),
    "a restart policy that is none": (
        '[restarts]\npolicies = ["sometimes"]\n',
        "--restart sometimes: POLICY or SERVICE=POLICY",
    ),
    "a sim-set of the motor": ('sim_set = ["motor.p_gain_l=1"]\n', "motor.p_gain_l"),
    "not TOML": ("[commander\n", "not TOML"),
    "a log level that is none": ('[network]\nlog_level = "loud"\n', "network.log_level 'loud': one of debug, info"),
}


@pytest.mark.parametrize(("text", "says"), INVALID.values(), ids=INVALID.keys())
def test_a_stack_that_cannot_be_run_exits_2_naming_why(tmp_path, capsys, text, says):
    stack_file = tmp_path / "s.toml"
    stack_file.write_text(text)
    code, _out, err = refused(capsys, "up", "--stack", str(stack_file))
    assert code == ExitStatus.CONFIG, err
    assert says in err, err


def test_a_run_flag_beside_a_stack_exits_2_naming_it(tmp_path, capsys):
    stack_file = tmp_path / "s.toml"
    stack_file.write_text("")
    code, _out, err = refused(capsys, "up", "--stack", str(stack_file), "--composed", "--mode", "realtime")
    assert code == ExitStatus.CONFIG
    assert "with --composed, --mode: the stack file says the whole run" in err


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--record-ros2"], "--record-ros2 without --ros2"),
        (["--tls"], "--tls without --secure"),
        (["--workers", "2"], "--workers without --composed"),
    ],
)
def test_flags_no_stack_holds_together_are_refused_by_print_stack_naming_them(capsys, flags, says):
    code, _out, err = refused(capsys, "up", *flags, "--print-stack")
    assert code == ExitStatus.CONFIG
    assert says in err
