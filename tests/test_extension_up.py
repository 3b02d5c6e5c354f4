"""``invent up --with``: the two examples beside the whole loop, secured (each shows in ``invent
status``, in ``report.json``, its keys in ``run.mcap``; a user service can touch only its own keys),
and the odometer killed mid-run ending the run naming it, in two runs whose lockstep outputs are
the same up to then. Three runs of the loop, shared by the tests that read them."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.keys import Keys, user_service_name
from services.recording.mcap_files import read_messages
from tests.harness import REPO, free_port, peer_session, run_invent, start_up, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys()
ODOMETER = f"{REPO / 'examples' / 'services' / 'odometer.py'}:Odometer"
PATROL = f"{REPO / 'examples' / 'services' / 'patrol.py'}:Patrol"
INTRUDER = f"{Path(__file__).parent / 'data' / 'extension' / 'services.py'}:Intruder"
ODOMETER_NAME, PATROL_NAME, INTRUDER_NAME = (user_service_name(n) for n in ("odometer", "patrol", "intruder"))


class Output:
    """An ``invent up`` process's output, read as it comes (a thread: the pipe never fills)."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.process = process
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line)

    @property
    def text(self) -> str:
        return "".join(self.lines)

    def pids(self) -> dict[str, int]:
        return {name: int(pid) for name, pid in re.findall(r"started (\w+) \(pid (\d+)\)", self.text)}

    def end(self, timeout: float = 60.0) -> int:
        try:
            code = self.process.wait(timeout)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait()
        self._thread.join(5)
        return code


@dataclass
class GoalsRun:
    output: str
    code: int
    status_lines: list[dict[str, Any]]
    report: dict[str, Any]
    topics: set[str]
    seen: dict[str, list[bytes]]


@pytest.fixture(scope="module")
def goals_run(tmp_path_factory: pytest.TempPathFactory) -> GoalsRun:
    """``invent up --secure --goals --with odometer --with patrol --with intruder`` in lockstep,
    watched as the observer, until the patrol has driven a corner; ``invent status`` meanwhile,
    then Ctrl-C: the run's end with its report."""
    report_dir = tmp_path_factory.mktemp("goals")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = Output(
        start_up(
            *("--secure", "--goals", "--mode", "lockstep"),
            *("--with", ODOMETER, "--with", PATROL, "--with", INTRUDER),
            *("--report", str(report_dir), "--listen", endpoint),
        )
    )
    seen: dict[str, list[bytes]] = {}
    observer = report_dir / "secrets" / "observer.json5"
    try:
        wait_until(lambda: observer.exists() or run.process.poll() is not None, 30, "the secure profile")
        with zenoh.open(zenoh.Config.from_file(str(observer))) as session:
            for key in (KEYS.motor_torque, KEYS.drive_target_velocity, KEYS.own(INTRUDER_NAME, "attempts")):
                seen[key] = []
                session.declare_subscriber(key, lambda s, key=key: seen[key].append(s.payload.to_bytes()))

            def completed() -> int:
                if run.process.poll() is not None:
                    raise AssertionError(f"invent up ended early:\n{run.text}")
                replies = [r.ok for r in session.get(KEYS.status(PATROL_NAME), timeout=2.0) if r.ok]
                return replies and json.loads(replies[0].payload.to_bytes())["completed"] >= 1

            wait_until(completed, 90, "the patrol to drive a corner")
        status = run_invent("status", "--connect", endpoint, "--robot", KEYS.robot, "--zenoh-config", str(observer))
        assert status.returncode == 0, status.stderr
        run.process.send_signal(signal.SIGINT)
        code = run.end()
    finally:
        if run.process.poll() is None:
            run.process.kill()
    report = json.loads((report_dir / "report.json").read_text())
    topics = {message.topic for message in read_messages(report_dir / "run.mcap").messages}
    lines = [json.loads(line) for line in status.stdout.splitlines() if line.strip()]
    return GoalsRun(run.text, code, lines, report, topics, seen)


def test_up_with_runs_each_example_beside_the_loop_its_lines_prefixed(goals_run):
    assert goals_run.code == 0, goals_run.output
    assert re.search(r"\[odometer +\] .*odometer from .*odometer.py:Odometer: lockstep at 10 Hz", goals_run.output)
    assert re.search(r"\[patrol +\] .*corner 0 completed: goal g", goals_run.output)
    assert "odometer gone" not in goals_run.output, "the sim waited for the odometer at every tick"


def test_each_example_shows_in_invent_status(goals_run):
    by_service = {line["service"]: line for line in goals_run.status_lines}
    assert by_service["odometer"]["alive"] and by_service["patrol"]["alive"]
    odometer, patrol = by_service["odometer"]["status"], by_service["patrol"]["status"]
    assert odometer["distance_m"] > 0.5 and odometer["lockstep"]["rate_hz"] == 10.0
    assert patrol["completed"] >= 1 and patrol["calls"]["replied"] >= 2, "its declared call, granted"
    sim = by_service["sim"]["status"]
    assert sim["lockstep_participants"]["odometer"]["output"] == "odometer/distance"


def test_each_example_shows_in_report_json(goals_run):
    health = goals_run.report["health"]
    assert set(health["user_services"]) == {"odometer", "patrol", "intruder"}
    assert health["user_services"]["patrol"]["completed"] >= 1
    assert health["services"]["odometer"] == {"bad_inputs": 0, "internal_errors": 0, "dropped_events": 0}
    assert health["lockstep"]["dropped_participants"] == []


def test_the_keys_of_each_example_are_in_run_mcap(goals_run):
    assert {
        KEYS.own(ODOMETER_NAME, "distance"),
        KEYS.status(ODOMETER_NAME),
        KEYS.own(PATROL_NAME, "progress"),
        KEYS.status(PATROL_NAME),
    } <= goals_run.topics


def test_with_secure_a_user_service_can_touch_only_its_own_keys(goals_run):
    attempts = goals_run.seen[KEYS.own(INTRUDER_NAME, "attempts")]
    assert len(attempts) >= 20, "its own key works"
    for key in (KEYS.motor_torque, KEYS.drive_target_velocity):
        assert goals_run.seen[key], f"{key} flows (the motor's, the drive's)"
        assert not [payload for payload in goals_run.seen[key] if b"intruder" in payload], key
    intruder = goals_run.report["health"]["user_services"]["intruder"]
    assert intruder["attempts"] >= 20 and intruder["goal_replies"] == 0, "drive/goal/send is not in its calls"


def _killed_straight(report_dir: Path) -> tuple[int, str, list[bytes]]:
    """``invent up --scenario straight --with odometer``, the odometer killed (SIGKILL) once it has
    output 15 times: the exit status, the output, the odometer's outputs as a subscriber got them
    (its journal, cut short by the kill, lacks its last ones)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = Output(
        start_up("--scenario", "straight", "--with", ODOMETER, "--report", str(report_dir), "--listen", endpoint)
    )
    try:
        outputs: list[bytes] = []
        with peer_session(endpoint) as session:
            session.declare_subscriber(
                KEYS.own(ODOMETER_NAME, "distance"), lambda sample: outputs.append(sample.payload.to_bytes())
            )

            def under_way() -> bool:
                if run.process.poll() is not None:
                    raise AssertionError(f"invent up ended early:\n{run.text}")
                return len(outputs) >= 15

            wait_until(under_way, 60, "15 outputs of the odometer")
        os.kill(run.pids()["odometer"], signal.SIGKILL)
        code = run.end()
    finally:
        if run.process.poll() is None:
            run.process.kill()
    assert read_messages(report_dir / "run.mcap").complete, "the run up to then, in a whole file"
    return code, run.text, outputs


@pytest.fixture(scope="module")
def killed_runs(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[int, str, list[bytes]]]:
    return [_killed_straight(tmp_path_factory.mktemp(f"straight{n}")) for n in range(2)]


def test_killing_a_user_service_mid_run_ends_the_run_naming_it(killed_runs):
    for code, output, _outputs in killed_runs:
        assert code == 1, output
        assert "odometer exited unexpectedly (killed by SIGKILL); stopped everything" in output


def test_the_lockstep_odometer_outputs_the_same_in_two_runs(killed_runs):
    """Each run cut short by the kill, at a moment of its own: every output both have is the same,
    byte for byte (stamps, distances, speeds)."""
    first, second = (outputs for _code, _output, outputs in killed_runs)
    common = min(len(first), len(second))
    assert common >= 10
    assert first[:common] == second[:common]
    assert json.loads(first[common - 1])["distance"] > 0.1
