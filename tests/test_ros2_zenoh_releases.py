"""rmw_zenoh's zenoh, kept: a ROS node's side (tests/zenoh_release_client.py) run on the zenoh
releases rmw_zenoh bundles, against the bridge on this project's zenoh.

rmw_zenoh bundles eclipse-zenoh 1.6.2 (Jazzy 0.2.9, Kilted 0.6.6, Rolling 0.10.1) and 1.8.0 (Jazzy
0.2.10, Kilted 0.6.7); 1.8.0 has no Python wheel, so 1.9.0 stands in for it. Each release gets a
side venv built from the package registry (eclipse-zenoh and the project's rosbags, nothing of the
project), kept under .cache/zenoh-releases/ and reused; where the registry cannot give it, its
tests are skipped, saying so. The loop runs twice on the kinematic engine, ``invent up --ros2
--teleop`` with its own router (``--listen``) and joining a zenoh 1.6.2 router in ``rmw_zenohd``'s
place (tests/zenoh_release_router.py, ``--connect``); against each, the client on each release,
a peer of the router as a ROS node is, sees ``/odom`` and ``/scan``, gets ``/robot_description``
from the publisher's cache as a late subscriber, drives by ``/cmd_vel``, stops the motor by
``/motor/stop`` (twists then move nothing) and clears it; then, with ``invent drive --goals``
beside the run, a NavigateToPose goal is accepted and SUCCEEDED.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.keys import Keys, Service
from tests.harness import REPO, InventProcess, call, free_port, invent_command, peer_session, wait_alive, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

RELEASES = ("1.6.2", "1.9.0")
"""The eclipse-zenoh releases rmw_zenoh bundles (1.9.0 for 1.8.0, which has no wheel)."""
ROUTER_RELEASE = "1.6.2"
CACHE = REPO / ".cache" / "zenoh-releases"
CLIENT = REPO / "tests" / "zenoh_release_client.py"
ROUTER = REPO / "tests" / "zenoh_release_router.py"
INSTALL_TIMEOUT_S = 600.0
STARTUP_TIMEOUT_S = 90.0
CLIENT_TIMEOUT_S = 120.0
ROBOT = Keys("rh0")


def _requirements(release: str) -> list[str]:
    """What the client needs: the release, and the rosbags the project's suite runs."""
    return [f"eclipse-zenoh=={release}", f"rosbags=={importlib.metadata.version('rosbags')}"]


def _complaint(stderr: str) -> str:
    """pip's first error line (``ERROR: No matching distribution found for ...``), or its last line."""
    lines = stderr.strip().splitlines() or ["no output"]
    return next((line for line in lines if line.startswith("ERROR:")), lines[-1])


def _side_python(release: str) -> Path | str:
    """The python of the side venv holding ``release``, built once from wheels and reused; or why it
    cannot be (the registry out of reach, no wheel of the release)."""
    venv = CACHE / f"eclipse-zenoh-{release}"
    python, ready = venv / "bin" / "python", venv / "installed.json"
    requirements = _requirements(release)
    if ready.exists() and json.loads(ready.read_text()) == requirements and python.exists():
        return python
    shutil.rmtree(venv, ignore_errors=True)
    steps = (
        [sys.executable, "-m", "venv", str(venv)],
        [str(python), "-m", "pip", "install", "-q", "--only-binary=:all:", *requirements],
    )
    for step in steps:
        try:
            done = subprocess.run(step, capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S, check=False)
        except subprocess.TimeoutExpired:
            done = None
        if done is None or done.returncode != 0:
            shutil.rmtree(venv, ignore_errors=True)
            said = _complaint(done.stderr) if done else "timed out"
            return (
                f"no side venv with {' '.join(requirements)} from the package registry ({' '.join(step[1:4])}: {said})"
            )
    ready.write_text(json.dumps(requirements))
    return python


@pytest.fixture(scope="module")
def side_pythons() -> dict[str, Path | str]:
    return {release: _side_python(release) for release in RELEASES}


def _python_of(side_pythons: dict[str, Path | str], release: str) -> Path:
    python = side_pythons[release]
    if isinstance(python, str):
        pytest.skip(python)
    return python


@dataclass
class Run:
    """``invent up --ros2 --teleop`` on the kinematic engine, and the test's session (the project's zenoh)."""

    endpoint: str
    session: zenoh.Session

    def bridge_status(self) -> dict[str, Any]:
        ok, status = call(self.session, ROBOT.status(Service.ROS2))
        assert ok, status
        return status


@contextmanager
def _release_router(python: Path) -> Iterator[str]:
    """A zenoh router of the side venv's release on a free loopback port; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen(
        [str(python), "-I", str(ROUTER), endpoint],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert router.stdin is not None and router.stdout is not None
    try:
        ready, _, _ = select.select([router.stdout], [], [], STARTUP_TIMEOUT_S)
        line = router.stdout.readline() if ready else ""
        assert line.strip() == f"listening on {endpoint}", f"the {ROUTER_RELEASE} router said {line!r}"
        yield endpoint
    finally:
        router.stdin.close()
        try:
            router.wait(15)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait()
    assert router.returncode == 0, router.stdout.read()


def _wait_alive_while_running(session: zenoh.Session, token_key: str, up: subprocess.Popen[str], log: Path) -> None:
    """Until ``token_key`` is alive; failing at once, with the run's output, if the run ends first."""
    alive = threading.Event()
    with session.liveliness().declare_subscriber(token_key, lambda _sample: alive.set(), history=True):
        wait_until(lambda: alive.is_set() or up.poll() is not None, STARTUP_TIMEOUT_S, token_key)
    assert alive.is_set(), f"invent up ended ({up.returncode}) before {token_key}:\n{log.read_text()[-3000:]}"


@contextmanager
def _teleop_run(router_flag: str, endpoint: str, log: Path) -> Iterator[Run]:
    """``invent up --ros2 --teleop --engine kinematic`` with ``router_flag`` (``--listen``, ``--connect``)
    ``endpoint``, until the bridge and the simulator are alive; SIGINT at the end, exit 0."""
    with log.open("w") as output:
        up = subprocess.Popen(
            invent_command("up", "--ros2", "--teleop", "--engine", "kinematic", router_flag, endpoint),
            cwd=REPO,
            stdout=output,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            with peer_session(endpoint) as session:
                for service in (Service.ROS2, Service.SIM):
                    _wait_alive_while_running(session, ROBOT.alive(service), up, log)
                yield Run(endpoint, session)
        finally:
            up.send_signal(signal.SIGINT)
            try:
                up.wait(60)
            except subprocess.TimeoutExpired:
                up.kill()
                up.wait()
    assert up.returncode == 0, log.read_text()[-3000:]


ROUTERS = ("project", f"zenoh-{ROUTER_RELEASE}")
"""The router the run and the clients meet at: the project's (``invent up --listen``), or a router of
rmw_zenoh's zenoh that ``invent up --connect`` joins."""


@pytest.fixture(scope="module", params=ROUTERS, ids=[f"{router}-router" for router in ROUTERS])
def run(
    request: pytest.FixtureRequest, side_pythons: dict[str, Path | str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Run]:
    log = tmp_path_factory.mktemp("zenoh-releases") / "up.log"
    if request.param == "project":
        with _teleop_run("--listen", f"tcp/127.0.0.1:{free_port()}", log) as project_run:
            yield project_run
        return
    with (
        _release_router(_python_of(side_pythons, ROUTER_RELEASE)) as endpoint,
        _teleop_run("--connect", endpoint, log) as release_run,
    ):
        yield release_run


@pytest.fixture(scope="module")
def goal_drive(run: Run) -> Iterator[Run]:
    """``invent drive --goals`` beside the run, once its teleop tests are done (a goal-mode drive
    commands zero between goals, which twists would fight), until the bridge sees its queryable."""
    with InventProcess("drive", "--goals", "--connect", run.endpoint, drain=True) as drive:
        wait_alive(run.session, ROBOT.alive(Service.DRIVE), STARTUP_TIMEOUT_S)
        wait_until(
            lambda: run.bridge_status()["navigate"]["drive_serves_goals"],
            STARTUP_TIMEOUT_S,
            "the bridge to see the drive's goal queryable",
        )
        yield run
        code, _out, err = drive.stop()
    assert code == 0, err[-3000:]


def _client(python: Path, endpoint: str, phase: str) -> dict[str, Any]:
    """The client's phase run with the side venv's python, isolated (``-I``: nothing of the project
    on its path); what it reports."""
    done = subprocess.run(
        [str(python), "-I", str(CLIENT), endpoint, phase],
        capture_output=True,
        text=True,
        timeout=CLIENT_TIMEOUT_S,
        check=False,
        env={key: value for key, value in os.environ.items() if not key.startswith("PYTHON")},
    )
    assert done.returncode == 0, done.stderr[-3000:]
    found: dict[str, Any] = json.loads(done.stdout.splitlines()[-1])
    return found


@pytest.mark.parametrize("release", RELEASES)
def test_a_ros_client_on_the_release_sees_odom_scan_and_a_late_urdf_drives_by_cmd_vel_and_stops_by_motor_stop(
    run: Run, side_pythons: dict[str, Path | str], release: str
):
    found = _client(_python_of(side_pythons, release), run.endpoint, "teleop")
    assert (found["zenoh"], found["routers"]) == (release, 1), "the release, a peer of the one router"
    assert found["odom"]["samples"] > 0 and found["odom"]["attachment_bytes"] == [33]
    assert found["odom"]["frames"] == ["odom", "base_link"]
    assert found["scan"]["samples"] > 0 and found["scan"]["frame"] == "base_scan" and found["scan"]["rays"] > 0
    assert found["robot_description"] == "<?xml", "a late subscriber gets the publisher's cached URDF"
    assert found["cmd_vel_moved_m"] > 0.15, "0.3 m/s for 1 s"
    assert found["motor_stop"] == {"success": True, "message": "motor state: stopped"}
    assert found["moved_while_stopped_m"] < 0.005, "twists for 0.5 s after /motor/stop"
    assert found["motor_clear"]["success"] and found["moved_after_clear_m"] > 0.05


@pytest.mark.parametrize("release", RELEASES)
def test_a_ros_client_on_the_release_has_a_navigate_to_pose_goal_accepted_and_succeeded(
    goal_drive: Run, side_pythons: dict[str, Path | str], release: str
):
    found = _client(_python_of(side_pythons, release), goal_drive.endpoint, "navigate")
    assert (found["zenoh"], found["routers"]) == (release, 1)
    assert found["accepted"]
    assert (found["result_status"], found["error_code"]) == ("succeeded", 0), found
    assert found["statuses"][-1] == 4 and set(found["statuses"]) <= {1, 2, 4}, "accepted, executing, succeeded"
    assert found["from_goal_m"] < 0.1, "in odometry, the goal 0.3 m ahead reached"
