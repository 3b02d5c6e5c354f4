"""``pip install .`` without extras: a fresh venv of the project alone (no PyBullet, mcap, matplotlib,
foxglove-sdk, rosbags) runs its router, the motor, the odometry, the localization and the drive, each
alive (its liveliness token and its status reply), ``invent status``, ``invent secrets --tls`` and
the kinematic engine; ``invent sim`` and the other commands of an extra exit 2
naming the extra to install.

The venv is built from the package registry once per pyproject.toml (under .cache/bare-venv/, which
git ignores) and reused while pyproject.toml is unchanged; each run reinstalls the project itself
into it (``--no-deps``, offline), so the commands run the code of the working tree. Where the registry
cannot give the venv, the test is skipped, saying why."""

from __future__ import annotations

import hashlib
import json
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from schemas.keys import Keys, Service
from services.cli.extras import EXTRA_OF_PACKAGE, ROS2, SIM, VIZ, Extra
from tests.harness import REPO, call, free_port, json_lines, peer_session, wait_alive

pytestmark = pytest.mark.slow

CACHE = REPO / ".cache" / "bare-venv"
PROJECT_FILES = ("pyproject.toml", "README.md", "schemas", "services", "sim_bridge")
"""What ``pip install .`` builds the package of (as the Dockerfile copies it)."""
BUILD_REQUIREMENT = "setuptools>=68"
"""pyproject.toml's build requirement, in the venv itself so that the project reinstalls offline."""
INSTALL_TIMEOUT_S = 900.0
COMMAND_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 15.0
KEYS = Keys("rh0")


def _complaint(stderr: str) -> str:
    """pip's first error line (``ERROR: ...``), or its last line."""
    lines = stderr.strip().splitlines() or ["no output"]
    return next((line for line in lines if line.startswith("ERROR:")), lines[-1])


def _project_copy(destination: Path) -> Path:
    for name in PROJECT_FILES:
        source = REPO / name
        if source.is_dir():
            shutil.copytree(source, destination / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, destination / name)
    return destination


def _run(step: list[str]) -> str | None:
    """None when ``step`` succeeded, else what it said."""
    try:
        done = subprocess.run(step, capture_output=True, text=True, timeout=INSTALL_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        return "timed out"
    return None if done.returncode == 0 else _complaint(done.stderr)


def _bare_venv() -> Path | str:
    """The venv's directory, with the working tree's project installed; or why it cannot be."""
    digest = hashlib.sha256((REPO / "pyproject.toml").read_bytes()).hexdigest()[:16]
    venv = CACHE / digest
    python, ready = venv / "bin" / "python", venv / "installed.json"
    with tempfile.TemporaryDirectory() as directory:
        project = str(_project_copy(Path(directory)))
        if not (ready.exists() and python.exists()):
            shutil.rmtree(CACHE, ignore_errors=True)  # venvs of earlier pyproject.tomls too
            steps = (
                [sys.executable, "-m", "venv", str(venv)],
                [str(python), "-m", "pip", "install", "-q", BUILD_REQUIREMENT, project],
            )
            for step in steps:
                said = _run(step)
                if said is not None:
                    shutil.rmtree(venv, ignore_errors=True)
                    return f"no bare venv from the package registry ({' '.join(step[1:4])}: {said})"
            ready.write_text(json.dumps({"pyproject.toml": digest}))
        reinstall = [str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--no-build-isolation"]
        said = _run([*reinstall, "--force-reinstall", project])
    if said is not None:
        return f"the project did not reinstall into {venv}: {said}"
    return venv


@pytest.fixture(scope="module")
def bare() -> Iterator[Path]:
    venv = _bare_venv()
    if isinstance(venv, str):
        pytest.skip(venv)
    yield venv


def test_the_bare_venv_has_no_package_of_an_extra(bare: Path) -> None:
    probe = "import importlib.util, sys; print([p for p in sys.argv[1:] if importlib.util.find_spec(p)])"
    done = subprocess.run(
        [str(bare / "bin" / "python"), "-c", probe, *EXTRA_OF_PACKAGE], capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "[]"


def _invent(bare: Path, *args: str) -> subprocess.Popen[str]:
    """The venv's ``invent`` (its console script), run outside the working tree: the installed code."""
    return subprocess.Popen(
        [str(bare / "bin" / "invent"), *args],
        cwd=bare,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_router_motor_odometry_localization_and_drive_run_alive_and_status_lists_them(bare: Path) -> None:
    """The venv's own router; each service connected to it alive (its token, its status reply, which
    counts bad input); ``invent status`` of the venv lists them; each stops on SIGINT with 0."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = _invent(bare, "router", "--listen", endpoint, "--log-level", "warning")
    connection = ("--connect", endpoint, "--log-level", "warning")
    started = {
        Service.MOTOR: _invent(bare, "motor", *connection),
        Service.ODOMETRY: _invent(bare, "odometry", *connection),
        Service.LOCALIZATION: _invent(bare, "localization", *connection),
        Service.DRIVE: _invent(bare, "drive", *connection, "--twist", "0.1", "0"),
    }
    try:
        with peer_session(endpoint) as session:
            for service, process in started.items():
                wait_alive(session, KEYS.alive(service), timeout=COMMAND_TIMEOUT_S)
                ok, status = call(session, KEYS.status(service))
                assert ok and "bad_input" in status, (service, status)
                assert process.poll() is None, f"{service} exited {process.returncode}"
        listed = _invent(bare, "status", *connection)
        out, err = listed.communicate(timeout=COMMAND_TIMEOUT_S)
        assert listed.returncode == 0, err
        alive = {(line["robot"], line["service"]) for line in json_lines(out) if line["alive"]}
        assert alive == {(KEYS.robot, str(service)) for service in started}, out
    finally:
        for process in started.values():
            process.send_signal(signal.SIGINT)
        outcomes = {
            service: (process.wait(STOP_TIMEOUT_S), process.communicate()[1]) for service, process in started.items()
        }
        router.send_signal(signal.SIGINT)
        router.communicate(timeout=STOP_TIMEOUT_S)
    for service, (code, err) in outcomes.items():
        assert "Traceback" not in err, f"{service}:\n{err}"
        assert code == 0, f"{service} exited {code}:\n{err}"


def test_the_kinematic_sim_runs_without_pybullet(bare: Path, endpoint: str) -> None:
    process = _invent(bare, "sim", "--engine", "kinematic", "--duration", "1", "--connect", endpoint)
    _out, err = process.communicate(timeout=COMMAND_TIMEOUT_S)
    assert process.returncode == 0, err
    assert "on the kinematic engine" in err and "finished: 1000 steps" in err, err


def test_secrets_makes_every_roles_credentials_and_the_tls_certificates(bare: Path, tmp_path: Path) -> None:
    """The ROS roles' grants included (their keys hold the interfaces' type hashes), without rosbags."""
    process = _invent(bare, "secrets", str(tmp_path / "secrets"), "--tls")
    _out, err = process.communicate(timeout=COMMAND_TIMEOUT_S)
    assert process.returncode == 0, err
    written = {path.name for path in (tmp_path / "secrets").iterdir()}
    assert {"motor.json5", "odometry.json5", "ros2.json5", "router.json5", "tls"} <= written, written


NEEDING: dict[str, tuple[tuple[str, ...], Extra]] = {
    "sim": (("sim",), SIM),
    "up": (("up", "--engine", "kinematic"), VIZ),
    "view": (("view",), VIZ),
    "ros2": (("ros2",), ROS2),
}


@pytest.mark.parametrize("name", list(NEEDING))
def test_a_command_of_an_extra_exits_2_saying_which_to_install(bare: Path, name: str) -> None:
    args, extra = NEEDING[name]
    process = _invent(bare, *args)
    _out, err = process.communicate(timeout=COMMAND_TIMEOUT_S)
    assert process.returncode == 2, err
    assert "Traceback" not in err
    assert (
        err.strip().splitlines()[-1] == f"invent {name}: needs {extra.brings}: pip install 'invent-zenoh[{extra.name}]'"
    )
