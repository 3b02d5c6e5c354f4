"""The robot description: seed defaults, strict loading, overrides, exit code 2 naming the field."""

import json
import math

import pytest

from services.config import SEED_NAMES, Config, ConfigError, load_config, parse_override
from tests.harness import run_invent

SEED_DEFAULTS = {
    "PGainL": 5.0,
    "PGainR": 5.0,
    "DGainL": 2.0,
    "DGainR": 2.0,
    "SimulatedOffsetX": 0.0,
    "SimulatedOffsetY": 0.0,
    "SimulatedOffsetAngle": 0.0,
    "leftWheelID": 0,
    "rightWheelID": 1,
    "radiusOfLeftWheel": 0.1,
    "radiusOfRightWheel": 0.1,
    "lengthOfAxle": 0.441,
    "radiusOfBodyArea": 0.45,
    "RotationAngleBorder": 3.1415927 / 180.0,
    "RhoBorder": 10000.0,
}


def _value(config: Config, dotted: str):
    section, field = dotted.split(".")
    return getattr(getattr(config, section), field)


def test_defaults_equal_the_seed_table():
    config = load_config()
    assert set(SEED_NAMES) == set(SEED_DEFAULTS)
    for seed_name, default in SEED_DEFAULTS.items():
        assert _value(config, SEED_NAMES[seed_name]) == pytest.approx(default, rel=1e-7), seed_name
    assert config.robot.name == "rh0"


def test_seed_names_table_is_in_the_docs():
    from tests.harness import REPO

    text = (REPO / "docs" / "configuration.md").read_text()
    for seed_name, key in SEED_NAMES.items():
        assert f"`{seed_name}`" in text and f"`{key}`" in text, seed_name


def test_file_values_and_overrides_apply_in_order(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text('[robot]\nname = "rh7"\nlength_of_axle = 0.5\n[motor]\np_gain_l = 1.5\np_gain_r = 2.5\n')
    config = load_config(path, {"motor.p_gain_r": 9.0, "robot.name": None})
    assert (config.robot.name, config.robot.length_of_axle) == ("rh7", 0.5)
    assert (config.motor.p_gain_l, config.motor.p_gain_r) == (1.5, 9.0)


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"motor.p_gain_l": -1.0}, "motor.p_gain_l"),
        ({"robot.length_of_axle": 0.0}, "robot.length_of_axle"),
        ({"robot.radius_of_left_wheel": "big"}, "robot.radius_of_left_wheel"),
        ({"robot.left_wheel_id": -1}, "robot.left_wheel_id"),
        ({"motor.no_such_gain": 1.0}, "no_such_gain"),
        ({"nowhere.x": 1.0}, "nowhere"),
        ({"sim.mode": "warp"}, "sim.mode"),
        ({"motor.target_angle": "other"}, "motor.target_angle"),
        ({"odometry.rho_border": math.inf}, "rho_border"),
        ({"robot.right_wheel_id": 0}, "right_wheel_id"),
        ({"robot.name": "a/b"}, "robot name"),
    ],
)
def test_invalid_values_raise_naming_the_field(overrides, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        load_config(overrides=overrides)


def test_override_values_are_read_as_toml():
    assert parse_override("motor.p_gain_l=3") == (["motor", "p_gain_l"], 3)
    assert parse_override("sim.mode=realtime") == (["sim", "mode"], "realtime")
    assert parse_override('robot.name="rh2"') == (["robot", "name"], "rh2")
    with pytest.raises(ConfigError, match="SECTION.KEY=VALUE"):
        parse_override("motor.p_gain_l")


def test_cli_prints_the_resolved_config():
    result = run_invent("config", "--set", "motor.d_gain_r=0.5", "--robot", "rh3")
    assert result.returncode == 0, result.stderr
    resolved = json.loads(result.stdout)
    assert resolved["motor"]["d_gain_r"] == 0.5
    assert resolved["robot"]["name"] == "rh3"


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["--set", "motor.p_gain_l=-3"], "motor.p_gain_l"),
        (["--set", "motor.bogus=1"], "bogus"),
        (["--robot", "a/b"], "robot"),
    ],
)
def test_cli_exits_2_naming_the_field(args, field):
    result = run_invent("config", *args)
    assert result.returncode == 2
    assert field in result.stderr
    assert result.stdout == ""


def test_cli_exits_2_on_an_invalid_file(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text('[robot]\nlength_of_axle = "wide"\n')
    result = run_invent("config", "--config", str(path))
    assert result.returncode == 2
    assert "robot.length_of_axle" in result.stderr
    path.write_text("[robot\n")
    result = run_invent("config", "--config", str(path))
    assert result.returncode == 2 and str(path) in result.stderr
    result = run_invent("config", "--config", str(tmp_path / "missing.toml"))
    assert result.returncode == 2 and "No such file" in result.stderr


def test_an_unset_service_flag_keeps_the_set_override():
    from services.cli.main import build_parser
    from services.service import config_from_args

    args = build_parser().parse_args(["motor", "--set", "motor.command_timeout=2.5"])
    assert config_from_args(args.service_command, args).motor.command_timeout == 2.5
    args = build_parser().parse_args(["motor", "--set", "motor.command_timeout=2.5", "--command-timeout", "1"])
    assert config_from_args(args.service_command, args).motor.command_timeout == 1.0
