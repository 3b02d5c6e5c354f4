"""``invent up --with examples/services/wander.py:Wander``: the wanderer drives in the built-in drive's
place (kinematic engine, lockstep) for over 60 simulated seconds in the ``room`` world (the loop in
separate processes) and in the furnished ``living_room`` (the loop ``--composed``, the wanderer a
process beside it), with no bump and no hold of the collision monitor, until Ctrl-C; in a
``--secure`` run it connects with the drive's credentials, and killed mid-run it ends the run naming
it, leaving ``report.json``; stopped by the motor's emergency stop, it gives up as the drive does.
One run of the loop per world, shared by the tests that read it."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.keys import Keys, Service
from schemas.topics import Method, MethodFamily
from services.security import Role
from tests.harness import REPO, call, free_port, peer_session, start_up, wait_until
from tests.test_extension_up import Output

pytestmark = pytest.mark.slow

KEYS = Keys()
WANDER = f"{REPO / 'examples' / 'services' / 'wander.py'}:Wander"
KINEMATIC_LOCKSTEP = ("--set", "sim.engine=kinematic", "--mode", "lockstep")
WANDERED_S = 60.0
"""Simulated seconds the wanderer must drive before Ctrl-C."""


@dataclass
class WanderRun:
    output: str
    code: int
    report: dict[str, Any]
    flags: tuple[str, ...] = ()


def _sim_time(session: zenoh.Session, run: Output) -> float:
    """The sim's time now (its status), 0 before it answers; fails the test if ``invent up`` ended."""
    if run.process.poll() is not None:
        raise AssertionError(f"invent up ended early:\n{run.text}")
    for reply in session.get(KEYS.status(Service.SIM), timeout=2.0):
        if reply.ok is not None:
            return float(json.loads(reply.ok.payload.to_bytes()).get("sim_time_s") or 0.0)
    return 0.0


def _wander(report_dir: Path, world: str, *flags: str, until: Callable[[Output, Path], None]) -> WanderRun:
    """``invent up --with WANDER`` in ``world``, kinematic, lockstep; ``until(run, report_dir)`` ends it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = Output(
        start_up(
            "--with",
            WANDER,
            *KINEMATIC_LOCKSTEP,
            *("--set", f"sim.world={world}", "--report", str(report_dir), "--listen", endpoint),
            *flags,
        )
    )
    try:
        until(run, report_dir)
        code = run.end(120)
    finally:
        if run.process.poll() is None:
            run.process.kill()
    return WanderRun(run.text, code, json.loads((report_dir / "report.json").read_text()), flags)


def _ctrl_c_after_a_minute(run: Output, report_dir: Path) -> None:
    with peer_session(run_endpoint(run)) as session:
        wait_until(lambda: _sim_time(session, run) >= WANDERED_S, 240, f"{WANDERED_S} s of simulation")
    run.process.send_signal(signal.SIGINT)


def run_endpoint(run: Output) -> str:
    args = list(run.process.args)  # type: ignore[arg-type]
    return str(args[args.index("--listen") + 1])


@pytest.fixture(scope="module", params=[("room", ()), ("living_room", ("--composed",))], ids=["room", "composed"])
def wandered(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> WanderRun:
    world, flags = request.param
    return _wander(tmp_path_factory.mktemp(world), world, *flags, until=_ctrl_c_after_a_minute)


def test_the_wanderer_drives_a_minute_in_the_drives_place_without_a_bump_or_a_hold_until_ctrl_c(wandered):
    assert wandered.code == 0, wandered.output
    assert "drives the robot at 10 Hz, in the drive's place" in wandered.output
    assert "started drive " not in wandered.output, "no built-in drive"
    assert "started wander (pid " in wandered.output, "the wanderer a process of its own"
    if "--composed" in wandered.flags:
        assert "started sim in this process" in wandered.output, "the loop composed beside it"
    report = wandered.report
    assert report["scenario"] == "wander" and report["mode"] == "lockstep"
    assert report["sim_time_s"] >= WANDERED_S
    assert report["health"]["safety"] == {"bumps": 0, "collision_monitor_holds": 0}
    assert report["health"]["lockstep"]["dropped_participants"] == [], "the sim waited for every command"
    assert report["outcome"] is None, "ended by Ctrl-C: no outcome, as a --goals run's"


@pytest.fixture(scope="module")
def killed(tmp_path_factory: pytest.TempPathFactory) -> tuple[WanderRun, str, Path]:
    """A ``--secure`` run in the room, watched as the observer: the wanderer's command line taken,
    then the wanderer killed (SIGKILL) after 5 simulated seconds."""
    command_line: list[str] = []

    def kill_after_5_s(run: Output, report_dir: Path) -> None:
        observer = report_dir / "secrets" / "observer.json5"
        wait_until(lambda: observer.exists() or run.process.poll() is not None, 30, "the secure profile")
        with zenoh.open(zenoh.Config.from_file(str(observer))) as session:
            wait_until(lambda: _sim_time(session, run) >= 5.0, 120, "5 s of simulation")
        command_line.extend(line for line in run.lines if "started wander (pid" in line)
        os.kill(run.pids()["wander"], signal.SIGKILL)

    report_dir = tmp_path_factory.mktemp("secure")
    wander_run = _wander(report_dir, "room", "--secure", until=kill_after_5_s)
    return wander_run, "".join(command_line), report_dir


def test_killed_mid_run_the_wanderer_ends_the_run_naming_it_and_leaves_report_json(killed):
    run, _line, _report_dir = killed
    assert run.code == 1, run.output
    assert "wander exited unexpectedly (killed by SIGKILL)" in run.output
    outcome = run.report["outcome"]
    assert outcome["outcome"] == "service_died" and outcome["service"] == "wander" and outcome["signal"] == "SIGKILL"
    assert outcome["t_s"] >= 5.0


def test_with_secure_the_wanderer_connects_with_exactly_the_drives_credentials(killed):
    run, line, report_dir = killed
    words = line.split()
    assert words[words.index("--zenoh-config") + 1] == str(report_dir / "secrets" / f"{Role.DRIVE}.json5"), line
    assert not (report_dir / "secrets" / "wander.json5").exists(), "no credentials of its own"
    assert "exited unexpectedly" not in run.output.split("started wander")[0], "it drove until killed"


def test_stopped_by_an_emergency_stop_the_wanderer_gives_up_as_the_drive_does(tmp_path):
    """``motor/gui/stop`` after 3 simulated seconds: the motor stays latched stopped for
    ``drive.give_up_after_stop`` (2 s), so the wanderer commands zero, publishes ``aborted`` and
    exits 3; the run ends with that outcome and exit status, as a scenario given up."""

    def emergency_stop(run: Output, report_dir: Path) -> None:
        with peer_session(run_endpoint(run)) as session:
            wait_until(lambda: _sim_time(session, run) >= 3.0, 120, "3 s of simulation")
            ok, _reply = call(session, KEYS.method(MethodFamily.GUI, Method.STOP))
            assert ok

    run = _wander(tmp_path, "room", until=emergency_stop)
    assert run.code == 3, run.output
    outcome = run.report["outcome"]
    assert outcome["outcome"] == "aborted" and outcome["reason"].startswith("an emergency stop (motor/gui/stop)")
    assert "the scenario was given up: exit 3" in run.output
