"""compose.yaml: a zenohd router plus one container per service, each a valid invent invocation."""


import yaml

from schemas.keys import Service
from services.cli import build_parser
from services.service import config_from_args
from tests.harness import REPO


def _compose() -> dict:
    return yaml.safe_load((REPO / "compose.yaml").read_text())


def test_services_are_the_router_plus_every_service():
    assert set(_compose()["services"]) == {"router"} | {str(service) for service in Service}


def test_router_is_zenohd_1_10_with_rest_and_a_memory_storage_on_invent():
    router = _compose()["services"]["router"]
    assert router["image"].startswith("eclipse/zenoh:1.10")
    assert "8000:8000" in router["ports"] and "7447:7447" in router["ports"]
    config_path = next(v.split(":")[0] for v in router["volumes"] if v.endswith(".json5:ro"))
    text = (REPO / config_path).read_text()
    assert "http_port: 8000" in text
    assert 'key_expr: "invent/**"' in text and 'volume: "memory"' in text


def test_every_command_is_a_valid_invent_invocation_connecting_to_the_router():
    parser = build_parser()
    for name, spec in _compose()["services"].items():
        if name == "router":
            continue
        command = spec["command"]
        assert command[0] == name
        args = parser.parse_args(command)
        assert args.connect == ["tcp/router:7447"], name
        config = config_from_args(args.service_command, args)
        assert config.robot.name == "rh0"


def test_the_drive_loops_the_square_scenario():
    command = _compose()["services"]["drive"]["command"]
    args = build_parser().parse_args(command)
    assert args.scenario.name == "square" and args.loop
