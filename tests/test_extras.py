"""The extras (pyproject.toml, services/cli/extras.py): the motor, odometry and drive processes import
none of their packages, and a command whose extra is missing exits 2 naming it, never a traceback.

Here in the project's venv (every extra installed): each process runs under a probe that writes the
modules it imported when it exits, or with the extras' packages hidden from every import finder (an
import of one raises ModuleNotFoundError naming it, as where it is not installed).
tests/test_bare_install.py runs the same commands from a ``pip install .`` without extras."""

from __future__ import annotations

import importlib.metadata
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import zenoh

from schemas.keys import Keys, Service, ServiceName
from services.cli.extras import EXTRA_OF_PACKAGE, ROS2, SIM, VIZ, Extra
from services.ros2 import graph, interfaces
from tests.harness import REPO, call, wait_alive

KEYS = Keys("rh0")
EXTRAS_PACKAGES = sorted(EXTRA_OF_PACKAGE)
LAZY_BASE_PACKAGES = ("cryptography",)
"""Base packages a service process must not load either: the certificates' (services/security/tls.py)."""
NOT_IN_MOTOR_NOR_ODOMETRY = ("ruamel", "scipy", "pyastar2d")
"""Base packages only the map files (drive and localization ``--map``) and the navigation need."""
STOP_TIMEOUT_S = 15.0

PROBE = """
import atexit, json, sys
report, blocked, argv = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3:]

class Absent:  # every finder answers nothing for a blocked package: imports fail as where it is not installed
    def __init__(self, finder):
        self.finder = finder
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in blocked or not hasattr(self.finder, "find_spec"):
            return None
        return self.finder.find_spec(name, path, target)

sys.meta_path[:] = [Absent(finder) for finder in sys.meta_path]
atexit.register(lambda: open(report, "w").write(json.dumps(sorted({m.partition(".")[0] for m in sys.modules}))))
from services.cli.main import main
sys.exit(main(argv))
"""
"""``python -c PROBE REPORT BLOCKED ARGS...``: ``invent ARGS`` with the packages of the JSON list
BLOCKED not found; at exit, the top-level modules it imported into the file REPORT."""


def probed(report: Path, *args: str, blocked: tuple[str, ...] = ()) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", PROBE, str(report), json.dumps(blocked), *args],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


SERVICES: dict[str, tuple[ServiceName, tuple[str, ...]]] = {
    "motor": (Service.MOTOR, ()),
    "odometry": (Service.ODOMETRY, ()),
    "drive": (Service.DRIVE, ("--twist", "0.1", "0")),
    "control": (Service.MOTOR, ("--engine", "kinematic", "--mode", "realtime")),  # the sim and the motor, composed
}


@pytest.mark.parametrize("command", list(SERVICES))
def test_a_motor_odometry_drive_or_control_process_imports_no_package_of_an_extra(
    command: str, endpoint: str, session: zenoh.Session, tmp_path: Path
) -> None:
    """Started for real against a router, alive (its token, its status reply), stopped: what it
    imported meanwhile holds none of the extras' packages (nor the lazily imported base ones)."""
    service, flags = SERVICES[command]
    report = tmp_path / "modules.json"
    process = probed(report, command, "--connect", endpoint, "--log-level", "warning", *flags)
    try:
        wait_alive(session, KEYS.alive(service))
        ok, status = call(session, KEYS.status(service))
        assert ok, status
    finally:
        process.send_signal(2)
        _out, err = process.communicate(timeout=STOP_TIMEOUT_S)
    assert report.exists(), f"invent {command} exited {process.returncode} without its report; stderr:\n{err}"
    imported = set(json.loads(report.read_text()))
    forbidden = {*EXTRAS_PACKAGES, *LAZY_BASE_PACKAGES}
    if command != "drive":
        forbidden |= set(NOT_IN_MOTOR_NOR_ODOMETRY)
    assert "zenoh" in imported and "services" in imported, "the probe saw the service's modules"
    assert imported & forbidden == set()


MISSING: dict[str, tuple[tuple[str, ...], Extra]] = {
    "sim": (("sim", "--duration", "1"), SIM),
    "view": (("view",), VIZ),
    "report": (("report", "no-such-run"), VIZ),
    "up": (("up", "--engine", "kinematic"), VIZ),
    "ros2": (("ros2",), ROS2),
    "export": (("export", "--ros2", "no-such-run.mcap"), ROS2),
}


@pytest.mark.parametrize("name", list(MISSING))
def test_a_command_whose_extra_is_missing_exits_2_naming_it(name: str, tmp_path: Path) -> None:
    """Every extra's packages unimportable: the command says which extra to install, in one line."""
    args, extra = MISSING[name]
    process = probed(tmp_path / "modules.json", *args, blocked=tuple(EXTRAS_PACKAGES))
    _out, err = process.communicate(timeout=60)
    assert process.returncode == 2, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].endswith(f"pip install 'invent-zenoh[{extra.name}]'"), err
    assert f"invent {args[0]}: needs {extra.brings}" in err


def test_invent_help_lists_every_command_and_says_which_are_not_installed(tmp_path: Path) -> None:
    process = probed(tmp_path / "modules.json", "--help", blocked=tuple(EXTRAS_PACKAGES))
    out, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert re.search(r"view\s+\(not installed: pip install 'invent-zenoh\[viz\]'\)", out), out
    for command in ("motor", "odometry", "drive", "sim", "ros2", "router", "status", "up"):
        assert re.search(rf"^\s+{command}\s", out, re.MULTILINE), command


def test_the_extras_packages_are_pyproject_tomls_extras() -> None:
    """services/cli/extras.py names, for each extra, the packages (as imported) its distributions
    install, as pyproject.toml lists them; [all] is every extra."""
    optional = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    distributions = importlib.metadata.packages_distributions()
    for extra in (SIM, VIZ, ROS2):
        names = {re.split(r"[<>=!~;\[ ]", requirement)[0].lower() for requirement in optional[extra.name]}
        installed = {package for package in extra.packages if package in distributions}
        assert installed == set(extra.packages), "every package of the extra is installed in the project's venv"
        assert {distributions[package][0].lower() for package in extra.packages} == names, extra.name
    assert optional["all"] == ["invent-zenoh[sim,viz,ros2]"]


def _graph_interfaces() -> set[str]:
    """Every interface an entity of the bridge's graph names, and those of its odometry services."""
    found: set[str] = set(graph.ODOMETRY_SERVICE_TYPES.values())
    for value in vars(graph).values():
        items = value.values() if isinstance(value, dict) else value if isinstance(value, tuple | list) else (value,)
        found |= {item.interface for item in items if isinstance(item, graph.Entity)}
    return found


def test_the_known_type_hashes_are_rosbags_and_cover_the_bridges_graph() -> None:
    """The grants hold the bridge's keys with these hashes: each is what rosbags computes, and no
    interface of the graph is missing (its grants would then need rosbags, the [ros2] extra)."""
    assert _graph_interfaces() <= set(interfaces.TYPE_HASHES)
    for name, known in interfaces.TYPE_HASHES.items():
        store = interfaces.messages() if "/msg/" in name else interfaces.services()
        assert store.hash_rihs01(name) == known, name
