"""The robot description: seed defaults, strict loading, overrides, exit code 2 naming the field."""

import json
import math
from pathlib import Path

import pytest

from services.config import (
    SEED_NAMES,
    Config,
    ConfigError,
    description_toml,
    load_config,
    parse_override,
    read_description,
)
from tests.harness import refused, run_invent

ROOT = Path(__file__).resolve().parent.parent

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
    assert parse_override("motor.p_gain_l=3") == ("motor.p_gain_l", 3)
    assert parse_override("sim.mode=realtime") == ("sim.mode", "realtime")
    assert parse_override('robot.name="rh2"') == ("robot.name", "rh2")
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
def test_cli_exits_2_naming_the_field(args, field, capsys):
    code, _out, stderr = refused(capsys, "config", *args)
    assert code == 2
    assert field in stderr


def test_cli_exits_2_on_an_invalid_file(tmp_path, capsys):
    path = tmp_path / "robot.toml"
    path.write_text('[robot]\nlength_of_axle = "wide"\n')
    code, _out, stderr = refused(capsys, "config", "--config", str(path))
    assert code == 2
    assert "robot.length_of_axle" in stderr
    path.write_text("[robot\n")
    code, _out, stderr = refused(capsys, "config", "--config", str(path))
    assert code == 2 and str(path) in stderr
    result = run_invent("config", "--config", str(tmp_path / "missing.toml"))
    assert result.returncode == 2 and "No such file" in result.stderr


def test_an_unset_service_flag_keeps_the_set_override():
    from services.cli.flags import config_from_args
    from services.cli.main import build_parser

    args = build_parser().parse_args(["motor", "--set", "motor.command_timeout=2.5"])
    assert config_from_args(args.service_cli, args).motor.command_timeout == 2.5
    args = build_parser().parse_args(["motor", "--set", "motor.command_timeout=2.5", "--command-timeout", "1"])
    assert config_from_args(args.service_cli, args).motor.command_timeout == 1.0


OPTIONAL_FIELDS = (
    "motor.max_vx",
    "motor.max_ax",
    "motor.max_w",
    "motor.max_aw",
    "motor.max_vx_reverse",
    "motor.max_ax_reverse",
    "motor.max_decel_x",
    "motor.max_decel_x_reverse",
    "motor.max_jerk_x",
    "motor.max_jerk_x_falling",
    "motor.max_w_reverse",
    "motor.max_aw_reverse",
    "motor.max_decel_w",
    "motor.max_decel_w_reverse",
    "motor.max_jerk_w",
    "motor.max_jerk_w_falling",
    "sim.world",
    "sim.brake_after",
    "localization.seed",
    "drive.give_up_after_stop",
    "drive.time_limit_factor",
    "record.max_size",
    "record.max_duration",
    "record.split_size",
    "record.split_duration",
    "navigation.map",
)


@pytest.mark.parametrize("dotted", OPTIONAL_FIELDS)
def test_none_turns_an_optional_parameter_off_in_a_file_and_in_set(tmp_path, dotted):
    section, field = dotted.split(".")
    path = tmp_path / "robot.toml"
    path.write_text(f'[{section}]\n{field} = "none"\n')
    assert _value(load_config(path), dotted) is None
    _, value = parse_override(f"{dotted}=none")
    assert _value(load_config(overrides={dotted: value}), dotted) is None
    assert _value(load_config(overrides={dotted: "None"}), dotted) is None


def test_the_optional_parameters_are_the_ones_documented():
    from services.config import SECTIONS, optional_fields

    found = {f"{name}.{field}" for name, section in SECTIONS.items() for field in optional_fields(section)}
    assert found == set(OPTIONAL_FIELDS)
    documented = (ROOT / "docs" / "configuration.md").read_text()
    assert all(f"`{dotted}`" in documented for dotted in OPTIONAL_FIELDS)


@pytest.mark.parametrize("value", ["0", "inf", "-1", "nope"])
def test_a_limit_that_cannot_be_taken_says_how_to_turn_it_off(value):
    result = run_invent("config", "--set", f"motor.max_vx={value}")
    assert result.returncode == 2
    assert "max_vx" in result.stderr and 'write "none" to turn it off' in result.stderr


def test_a_motor_without_limits_commands_what_it_is_told():
    from schemas.messages import NANOSECONDS_PER_SECOND
    from services.motor.core import MotorCore

    overrides = {f"motor.{limit}": "none" for limit in ("max_vx", "max_ax", "max_w", "max_aw")}
    unlimited, limited = load_config(overrides=overrides), load_config()
    step_ns = NANOSECONDS_PER_SECOND // 1000
    references = []
    for config in (unlimited, limited):
        core = MotorCore(config.robot, config.motor, config.input)
        core.set_target(2.5, 4.0)  # above the default limits of 1 m/s and 3 rad/s, at once
        core.step(0, [0.0, 0.0])
        core.step(step_ns, [0.0, 0.0])
        references.append(core.dq_ref)
    radius, half_axle = unlimited.robot.radius_of_left_wheel, unlimited.robot.half_axle
    expected = ((2.5 - 4.0 * half_axle) / radius, (2.5 + 4.0 * half_axle) / radius)
    assert references[0] == pytest.approx(expected)
    assert abs(references[1][0]) < abs(expected[0]) and abs(references[1][1]) < abs(expected[1])


def test_a_description_written_back_loads_as_the_one_read(tmp_path):
    """What `invent calibrate umbmark -o` writes: the file and the overrides, as written, back as TOML."""
    path = tmp_path / "robot.toml"
    path.write_text(
        '[robot]\nname = "rh3"\nlength_of_axle = 0.45\n\n[motor]\nmax_vx = "none"\n\n'
        "[ros2]\npose_covariance = [0.1, 0.1, 0.1, 0.1, 0.1, 1e-05]\n"
    )
    overrides = {"odometry.axle_scale": 1.0123456789012345, "sim.world": "bump", "drive.give_up_after_stop": None}
    description = read_description(path, overrides)
    assert description["odometry"] == {
        "axle_scale": 1.0123456789012345
    } and "give_up_after_stop" not in description.get("drive", {})
    written = tmp_path / "written.toml"
    written.write_text(description_toml(description))
    assert load_config(written) == load_config(path, overrides)
    assert load_config(written).odometry.axle_scale == 1.0123456789012345
    assert load_config(written).motor.max_vx is None and load_config(written).ros2.pose_covariance[5] == 1e-05
    assert description_toml({"odometry": {"straight_step": "seed"}, "sim": {"brake_after": None}}) == (
        '[odometry]\nstraight_step = "seed"\n\n[sim]\nbrake_after = "none"\n'
    )
