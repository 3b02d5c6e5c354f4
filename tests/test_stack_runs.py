"""``invent up FLAGS`` and ``invent up --stack S`` where S is ``invent up FLAGS --print-stack``'s
output: the same report, apart from the wall time (docs/stack.md). Lockstep runs, so that the
report is the same bit for bit: a square, a fleet, and goals (a goal file's: ``--goals`` waits for
goals sent while it runs, a realtime run no two of which are alike) with the ROS 2 bridge."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.harness import REPO, free_port, run_invent

pytestmark = pytest.mark.slow

FAST = ("--composed", "--engine", "kinematic")
RUNS = {
    "square": [*FAST],
    "fleet": [*FAST, "--fleet", str(REPO / "examples/fleets/two_squares.toml")],
    "goals with ros2": [*FAST, "--goal-file", str(REPO / "examples/goals/u_trap.toml"), "--mode", "lockstep", "--ros2"],
}
WALL_CLOCK_FIELDS = ("wall_time_s", "real_time_factor")
RUN_TIMEOUT_S = 240.0


def _without_wall_clock(report: object) -> object:
    """The report with every wall-clock figure left out, at any depth (a fleet's robots have theirs)."""
    if isinstance(report, dict):
        return {key: _without_wall_clock(value) for key, value in report.items() if key not in WALL_CLOCK_FIELDS}
    if isinstance(report, list):
        return [_without_wall_clock(value) for value in report]
    return report


def _report(directory: Path) -> object:
    return _without_wall_clock(json.loads((directory / "report.json").read_text()))


def _listen() -> list[str]:
    """Where a run's router listens: a free port of its own."""
    return ["--listen", f"tcp/127.0.0.1:{free_port()}"]


@pytest.mark.parametrize("flags", RUNS.values(), ids=RUNS.keys())
def test_the_stack_printed_from_the_flags_runs_what_the_flags_run(tmp_path, flags):
    by_flags, by_stack = tmp_path / "flags", tmp_path / "stack"
    printed = run_invent("up", *flags, *_listen(), "--report", str(by_stack), "--print-stack")
    assert printed.returncode == 0, printed.stderr
    stack_file = tmp_path / "run.toml"
    stack_file.write_text(printed.stdout)
    assert not by_stack.exists(), "--print-stack runs nothing"
    ran = run_invent("up", *flags, *_listen(), "--report", str(by_flags), timeout=RUN_TIMEOUT_S)
    assert ran.returncode == 0, ran.stderr[-3000:]
    again = run_invent("up", "--stack", str(stack_file), timeout=RUN_TIMEOUT_S)
    assert again.returncode == 0, again.stderr[-3000:]
    assert _report(by_stack) == _report(by_flags)
