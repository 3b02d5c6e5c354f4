"""compose.yaml: a zenohd router with access control plus client containers, the control path (the
sim and the motor composed in one, or with compose.split.yaml a container each) and one per other
service, each a valid invent invocation with its own role's credentials, the script that makes them,
and the profiles that let exactly one commander (the drive's scenario, ROS 2's /cmd_vel, or the drive
in goal mode) drive the robot."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
import zenoh

from schemas.keys import Keys, Service, user_service_name
from services.cli.control import composed_plans
from services.cli.flags import config_from_args
from services.cli.main import build_parser
from services.exits import ExitStatus
from services.security import (
    DICTIONARY,
    ROUTER_CONFIG,
    Flow,
    Message,
    Role,
    UserServiceGrant,
    grants,
    user_service_grants,
)
from tests.harness import REPO, refused

SECRETS_DIR = "./docker/secure/secrets"
MOUNTED_SECRETS = "/secrets"
ROLE_FILE_IN_CONTAINER = "/run/secrets/zenoh.json5"
GOALS_DRIVE = "drive-goals"
"""The drive of the `goals` profile: the drive in goal mode, with the drive's credentials."""
CONTROL = "control"
"""The control path's container: ``invent control``, the sim and the motor composed in one process."""
SPLIT = {str(Service.SIM), str(Service.MOTOR)}
"""compose.split.yaml's containers, in place of the control container."""
ROLES = {
    **{str(service): Role(service.value) for service in Service},
    "view": Role.OBSERVER,
    GOALS_DRIVE: Role.DRIVE,
    CONTROL: Role.CONTROL,
}
"""Each client container's role: its service's own, the live view's the observer's (it only watches),
the control path's the sim's and the motor's together."""
CONTROL_PATH = {CONTROL, *SPLIT}
COMMANDS = {name: str(role) if name == GOALS_DRIVE else name for name, role in ROLES.items()}
"""The `invent` command each container runs: its name's, the goal drive's `drive`."""
USER_SERVICES = {"odometer": "./examples/services:/services:ro"}
"""The services of one's own (docs/extending.md), in the `extension` profile: each runs `invent service`
with its file mounted (its directory, here), with credentials of its own (<name>.json5)."""


def _compose(*overrides: str) -> dict:
    """compose.yaml with ``overrides`` (files beside it) merged over it as docker compose merges
    them here: a service's keys replaced, new services and secrets added."""
    compose = yaml.safe_load((REPO / "compose.yaml").read_text())
    for name in overrides:
        override = yaml.safe_load((REPO / name).read_text())
        for service, spec in override["services"].items():
            compose["services"].setdefault(service, {}).update(spec)
        compose["secrets"].update(override.get("secrets", {}))
    return compose


def _services(*overrides: str) -> dict:
    """The client containers that run: those of no profile a deployment never names."""
    return {
        name: spec
        for name, spec in _compose(*overrides)["services"].items()
        if name != "router" and spec.get("profiles") != ["composed-control-path"]
    }


def test_services_are_the_router_plus_every_service():
    others = {"view", GOALS_DRIVE, *USER_SERVICES} | {str(service) for service in Service} - SPLIT
    assert set(_compose()["services"]) == {"router", CONTROL} | others
    assert set(_services("compose.split.yaml")) == SPLIT | others, "the sim and the motor apart, no control"


def test_router_reads_the_generated_config_and_publishes_rest_on_loopback_only():
    router = _compose()["services"]["router"]
    assert router["image"].startswith("eclipse/zenoh:1.10")
    assert router["command"] == ["-c", f"{MOUNTED_SECRETS}/{ROUTER_CONFIG}"]
    assert f"{SECRETS_DIR}:{MOUNTED_SECRETS}:ro" in router["volumes"]
    assert set(router["ports"]) == {"7447:7447", "127.0.0.1:8000:8000"}


@pytest.mark.parametrize("overrides", [(), ("compose.split.yaml",)], ids=["composed", "split"])
def test_every_service_is_a_client_with_only_its_own_roles_credentials(overrides):
    parser = build_parser()
    declared = _compose(*overrides)["secrets"]
    for name, spec in _services(*overrides).items():
        command = spec["command"]
        if name in USER_SERVICES:
            assert command[:2] == ["service", f"/services/{name}.py:{name.title()}"], name
            assert spec["secrets"] == [{"source": name, "target": Path(ROLE_FILE_IN_CONTAINER).name}], name
            assert declared[name] == {"file": f"{SECRETS_DIR}/{name}.json5"}, name
            assert spec["volumes"] == [USER_SERVICES[name]] and spec["profiles"] == ["extension"], name
            assert build_parser().parse_args(command).zenoh_config == ROLE_FILE_IN_CONTAINER
            continue
        assert command[0] == COMMANDS[name]
        args = parser.parse_args(command)
        assert args.connect == ["tcp/router:7447"], name
        assert args.zenoh_config == ROLE_FILE_IN_CONTAINER, name
        role = ROLES[name]
        assert spec["secrets"] == [{"source": str(role), "target": Path(ROLE_FILE_IN_CONTAINER).name}], name
        assert declared[str(role)] == {"file": f"{SECRETS_DIR}/{role}.json5"}, name
        holds_motor = name in (CONTROL, str(Service.MOTOR))
        assert spec.get("volumes", []) == (["motor-state:/state"] if holds_motor else []), name
        assert config_from_args(getattr(args, "service_cli", None), args).robot.name == "rh0"


@pytest.mark.parametrize("overrides", [(), ("compose.split.yaml",)], ids=["composed", "split"])
def test_every_service_is_told_the_deployment_runs_in_realtime_so_no_reader_delays_it(overrides):
    """Each reads ``sim.mode`` realtime: a put that finds zenoh's queue full is dropped rather than
    wait (docs/protocol.md section 2.6), which the description's default, lockstep, would make it do."""
    parser = build_parser()
    for name, spec in _services(*overrides).items():
        args = parser.parse_args(spec["command"])
        if name == CONTROL:
            assert {str(plan.config.sim.mode) for _, plan in composed_plans(args)} == {"realtime"}
        else:
            assert config_from_args(getattr(args, "service_cli", None), args).sim.mode == "realtime", name


@pytest.mark.parametrize("overrides", [(), ("compose.split.yaml",)], ids=["composed", "split"])
def test_the_control_path_runs_with_rt_and_its_containers_grant_what_it_needs(overrides):
    parser = build_parser()
    for name, spec in _services(*overrides).items():
        args = parser.parse_args(spec["command"])
        control_path = name in CONTROL_PATH
        assert getattr(args, "rt", False) is control_path, name
        assert config_from_args(getattr(args, "service_cli", None), args).rt.enabled is control_path, name
        if control_path:
            assert set(spec["cap_add"]) == {"SYS_NICE", "IPC_LOCK"}, name
        else:
            assert "cap_add" not in spec and "ulimits" not in spec, name


@pytest.mark.parametrize("overrides", [(), ("compose.split.yaml",)], ids=["composed", "split"])
def test_the_router_and_the_control_path_share_the_control_paths_cpu_that_env_names(overrides):
    """What the control path sends through the router stays on one core; the other containers keep
    off it by themselves (rt.partition, on by default), so none of them has a cpuset."""
    services = _compose(*overrides)["services"]
    control_path = {"router", *CONTROL_PATH}
    env = dict(
        line.split("=", 1) for line in (REPO / ".env").read_text().splitlines() if line and not line.startswith("#")
    )
    assert env["INVENT_CONTROL_PATH_CPU"].isdigit()
    for name, spec in services.items():
        if name in control_path:
            assert spec["cpuset"].startswith("${INVENT_CONTROL_PATH_CPU:?"), name
        else:
            assert "cpuset" not in spec, name
            args = build_parser().parse_args(spec["command"])
            assert config_from_args(getattr(args, "service_cli", None), args).rt.partition, name


def test_the_live_view_listens_in_its_container_and_is_published_to_this_host_only():
    view = _compose()["services"]["view"]
    args = build_parser().parse_args(view["command"])
    assert (args.host, args.port) == ("0.0.0.0", 8765)
    assert view["ports"] == [f"127.0.0.1:{args.port}:{args.port}"]


def test_the_drive_loops_the_square_scenario():
    command = _compose()["services"]["drive"]["command"]
    args = build_parser().parse_args(command)
    assert args.scenario == "square" and args.loop


def test_the_goals_profiles_drive_waits_for_goals():
    args = build_parser().parse_args(_compose()["services"][GOALS_DRIVE]["command"])
    assert args.goals and args.scenario is None and args.goal_file is None


def _default_profiles() -> set[str]:
    """The profiles `docker compose up` runs with no --profile: COMPOSE_PROFILES of the .env file
    beside compose.yaml (a --profile flag replaces them)."""
    settings = dict(
        line.split("=", 1) for line in (REPO / ".env").read_text().splitlines() if line and not line.startswith("#")
    )
    return set(settings["COMPOSE_PROFILES"].split(","))


def _running(profiles: set[str]) -> set[str]:
    """The services compose starts with these profiles: those without profiles, and those of one of them."""
    return {name for name, spec in _compose()["services"].items() if set(spec.get("profiles", profiles)) & profiles}


def _commanders() -> set[str]:
    """The containers whose role may put the robot's target velocity (the motor takes the newest)."""
    target = Keys("rh0").drive_target_velocity
    return {
        name
        for name, role in ROLES.items()
        if any(
            Message.PUT in grant.messages and grant.flow is Flow.INGRESS and target in grant.key_exprs
            for grant in grants(role, Keys("rh0"))
        )
    }


def test_the_drives_and_the_ros2_bridge_are_the_commanders():
    assert _commanders() == {str(Service.DRIVE), GOALS_DRIVE, str(Service.ROS2)}


def test_the_default_profile_runs_the_drives_scenario_and_no_ros2_bridge():
    assert _default_profiles() == {"scenario"}
    running = _running(_default_profiles())
    assert running == set(_compose()["services"]) - {str(Service.ROS2), GOALS_DRIVE, *USER_SERVICES}
    assert running & _commanders() == {str(Service.DRIVE)}


def test_the_ros2_profile_runs_the_bridge_and_no_drive_so_the_robot_follows_cmd_vel():
    running = _running({"ros2"})
    assert running == set(_compose()["services"]) - {str(Service.DRIVE), GOALS_DRIVE, *USER_SERVICES}
    assert running & _commanders() == {str(Service.ROS2)}


def test_the_goals_profile_runs_the_drive_in_goal_mode_and_no_other_commander():
    running = _running({"goals"})
    assert running == set(_compose()["services"]) - {str(Service.DRIVE), str(Service.ROS2), *USER_SERVICES}
    assert running & _commanders() == {GOALS_DRIVE}


def test_every_profile_has_exactly_one_commander():
    profiles = {profile for spec in _compose()["services"].values() for profile in spec.get("profiles", [])}
    assert profiles == {"scenario", "ros2", "goals", "extension"}
    for profile in profiles - {"extension"}:
        assert len(_running({profile}) & _commanders()) == 1, profile
    # the extension profile adds services of one's own beside a commander, and commands nothing itself
    assert _running({"extension"}) - _running({"none"}) == set(USER_SERVICES)
    assert not _running({"extension"}) & _commanders()
    target = Keys("rh0").drive_target_velocity
    for name in USER_SERVICES:
        granted = user_service_grants(UserServiceGrant(user_service_name(name)), Keys("rh0"))
        assert not [grant for grant in granted if Message.PUT in grant.messages and target in grant.key_exprs]


def test_make_secrets_writes_the_files_compose_mounts(tmp_path):
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    result = subprocess.run(
        [str(REPO / "docker" / "secure" / "make-secrets"), str(tmp_path / "secrets")],
        cwd=REPO,
        env=environment,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    written = tmp_path / "secrets"
    for name in _compose()["secrets"]:
        assert (written / f"{name}.json5").exists(), name
    router = json.loads(str(zenoh.Config.from_file(str(written / ROUTER_CONFIG))))
    assert router["mode"] == "router"
    assert router["listen"]["endpoints"] == ["tcp/[::]:7447"]
    assert router["transport"]["auth"]["usrpwd"]["dictionary_file"] == f"{MOUNTED_SECRETS}/{DICTIONARY}"
    assert router["access_control"]["enabled"] is True
    assert router["plugins"]["rest"]["http_port"] == 8000
    assert router["plugins"]["storage_manager"]["storages"]["invent"] == {"key_expr": "invent/**", "volume": "memory"}


def test_no_credentials_are_committed_or_copied_into_the_image():
    assert SECRETS_DIR.removeprefix("./") + "/" in (REPO / ".gitignore").read_text().splitlines()
    assert SECRETS_DIR.removeprefix("./") in (REPO / ".dockerignore").read_text().splitlines()


@pytest.mark.parametrize("container", [CONTROL, str(Service.MOTOR)])
def test_the_motors_state_file_is_on_a_volume_so_an_emergency_stop_survives_a_restart(container):
    """And the same volume composed or split: a stop latched in one layout holds in the other."""
    compose = _compose("compose.split.yaml")
    args = build_parser().parse_args(compose["services"][container]["command"])
    volume, mount = compose["services"][container]["volumes"][0].split(":")
    assert volume in compose["volumes"]
    assert Path(args.state).parent == Path(mount)


def test_the_control_container_composes_the_sim_and_the_motor_in_realtime():
    args = build_parser().parse_args(_compose()["services"][CONTROL]["command"])
    assert args.command == CONTROL and args.mode == "realtime"


def test_the_real_time_override_gives_the_control_path_a_budget_within_the_daemons():
    """compose.rt.yaml, for hosts with real-time group scheduling (docs/realtime.md): a share of
    the budget `dockerd --cpu-rt-runtime=950000` holds, to the control path only."""
    override = yaml.safe_load((REPO / "compose.rt.yaml").read_text())["services"]
    assert set(override) == {CONTROL}
    assert all(set(spec) == {"cpu_rt_runtime"} for spec in override.values())
    assert sum(spec["cpu_rt_runtime"] for spec in override.values()) <= 950_000


def test_the_committed_compose_yaml_is_invent_composes_output(capsys):
    code, out, err = refused(capsys, "compose")
    assert code == ExitStatus.OK, err
    assert out == (REPO / "compose.yaml").read_text(), "regenerate it: invent compose > compose.yaml"


def test_the_compose_of_a_stack_gives_every_service_its_settings_and_runs_its_own_services(tmp_path, capsys):
    flags = ["--scenario", "figure8", "--set", "lidar.noise=0.01", "--robot", "rh3"]
    code, stack, err = refused(
        capsys, "up", *flags, "--with", "examples/services/fix_ledger.py:FixLedger", "--print-stack"
    )
    assert code == ExitStatus.OK, err
    (tmp_path / "s.toml").write_text(stack)
    code, out, err = refused(capsys, "compose", "--stack", str(tmp_path / "s.toml"))
    assert code == ExitStatus.OK, err
    services = yaml.safe_load(out)["services"]
    assert "view" not in services, "no live view in the stack, none in its compose"
    assert "odometer" not in services
    ledger = services["fixes"]  # the service's name, as its class says
    assert ledger["profiles"] == ["extension"] and ledger["volumes"] == ["./examples/services:/services:ro"]
    assert ledger["command"][:2] == ["service", "/services/fix_ledger.py:FixLedger"]
    assert ledger["secrets"] == [{"source": "fixes", "target": "zenoh.json5"}]
    parser = build_parser()
    for name, spec in services.items():
        if name == "router":
            continue
        args = parser.parse_args(spec["command"])
        assert args.robot == "rh3" and "lidar.noise=0.01" in args.set, name
    assert parser.parse_args(services["drive"]["command"]).scenario == "figure8"


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--fleet", str(REPO / "examples/fleets/two_squares.toml")], "a fleet"),
        (["--mode", "lockstep"], "lockstep"),
        (["--composed"], "composed processes"),
    ],
)
def test_a_stack_no_compose_deployment_runs_exits_2_naming_what(tmp_path, capsys, flags, says):
    code, stack, err = refused(capsys, "up", *flags, "--print-stack")
    assert code == ExitStatus.OK, err
    (tmp_path / "s.toml").write_text(stack)
    code, _out, err = refused(capsys, "compose", "--stack", str(tmp_path / "s.toml"))
    assert code == ExitStatus.CONFIG
    assert f"invent compose: {says}" in err
