"""``invent up --sim-set SECTION.KEY=VALUE``: the simulated robot differs from the description the
other services read. Refused before anything starts (exit 2 naming it): a key that is not of the
body or its sensors' noise, a text that is not KEY=VALUE, a value the sim's description refuses, a
fleet. ``invent control --sim-set`` (a realtime run's control path) gives it to the sim's plan and
not the motor's. End to end (slow): a composed kinematic run of ``straight`` with the right wheel
5 % larger in the simulator alone: the ground truth (``sim/body_pose``) curves left while the
odometry (``odometry/pose``), on the description's wheels, believes it went straight."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from schemas.codec import decode
from schemas.keys import Keys
from schemas.messages import TimedDoubleSeq, TimedPosition
from services.cli.control import composed_plans
from services.cli.main import build_parser
from services.config import SIM_BODY_KEYS, ConfigError, RobotConfig, parse_sim_set
from services.exits import ExitStatus
from services.launch.plan import UpPlan
from services.launch.service_plans import BUILT_IN, ChildPlan, ControlPlan, service_argv
from services.motor.service import MotorOptions
from services.recording.mcap_files import read_messages
from services.runtime.session import free_port
from sim_bridge.bridge import SimOptions
from tests.harness import REPO, invent_command, refused

KEYS = Keys("rh0")
RADIUS = RobotConfig().radius_of_right_wheel
LARGER = round(RADIUS * 1.05, 6)


def test_the_allowed_keys_are_the_body_and_the_sensors_noise_shared_with_calibrate():
    from services.cli import calibrate

    assert {"robot.radius_of_right_wheel", "robot.length_of_axle", "lidar.noise", "lidar.seed"} <= set(SIM_BODY_KEYS)
    assert {"imu.gyro_noise", "imu.accel_noise", "imu.seed"} <= set(SIM_BODY_KEYS)
    assert not [key for key in SIM_BODY_KEYS if key.split(".")[0] in ("motor", "odometry", "localization", "drive")]
    assert calibrate.SIM_BODY_KEYS is SIM_BODY_KEYS
    assert parse_sim_set(["lidar.noise=0.01", "robot.length_of_axle=0.45"]) == {
        "lidar.noise": 0.01,
        "robot.length_of_axle": 0.45,
    }
    with pytest.raises(ConfigError, match="--sim-set odometry.left_scale: only the simulated body"):
        parse_sim_set(["odometry.left_scale=1.1"])


def test_the_sim_alone_gets_its_overrides_after_the_common_ones():
    plan = UpPlan(sim_set=("lidar.noise=0.02", "robot.radius_of_right_wheel=0.11"))
    control = ControlPlan(ChildPlan("control", BUILT_IN["motor"][0], MotorOptions()), SimOptions(), plan.sim_set)
    assert service_argv(control)[-4:] == [
        "--sim-set",
        "lidar.noise=0.02",
        "--sim-set",
        "robot.radius_of_right_wheel=0.11",
    ]
    config = plan.sim_config()
    assert config.lidar.noise == 0.02 and config.robot.radius_of_right_wheel == 0.11
    assert plan.description.load().lidar.noise == 0.0, "the description the other services read is unchanged"


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--sim-set", "motor.p_gain_l=1"], "--sim-set motor.p_gain_l: only the simulated body"),
        (["--sim-set", "odometry.left_scale=1.1"], "--sim-set odometry.left_scale"),
        (["--sim-set", "lidar.noise"], "--sim-set 'lidar.noise' must be KEY=VALUE"),
        (["--sim-set", "robot.radius_of_right_wheel=-0.1"], "robot.radius_of_right_wheel"),
        (["--sim-set", "lidar.noise=-1"], "lidar.noise"),
        (["--sim-set", "imu.seed=many"], "imu.seed"),
        (["--sim-set", "lidar.noise=0.01", "--fleet", "fleet.toml"], "--sim-set with --fleet"),
    ],
    ids=["motor", "odometry", "not-key-value", "negative-radius", "negative-noise", "seed-not-a-number", "fleet"],
)
def test_a_sim_set_refused_exits_2_naming_it_before_anything_starts(capsys, tmp_path, flags, says):
    code, _out, err = refused(capsys, "up", *flags, "--report", str(tmp_path / "run"), "--listen", "tcp/127.0.0.1:9")
    assert code == ExitStatus.CONFIG, err
    assert says in err
    assert not (tmp_path / "run").exists(), "nothing started, nothing written"


def test_invent_control_gives_its_sim_set_to_the_sim_not_the_motor(capsys):
    args = build_parser("control").parse_args(
        ["control", "--set", "lidar.noise=0.01", "--sim-set", f"robot.radius_of_right_wheel={LARGER}"]
    )
    plans = dict(composed_plans(args))
    assert plans["sim"].config.robot.radius_of_right_wheel == LARGER
    assert plans["motor"].config.robot.radius_of_right_wheel == RADIUS
    assert plans["sim"].config.lidar.noise == plans["motor"].config.lidar.noise == 0.01
    code, _out, err = refused(capsys, "control", "--sim-set", "motor.p_gain_l=1")
    assert code == ExitStatus.CONFIG
    assert "--sim-set motor.p_gain_l" in err


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_invent_controls_mode_is_the_motors_too(mode):
    """Its motor's publishers meet congestion as the run's mode says (docs/protocol.md section 2.6)."""
    plans = dict(composed_plans(build_parser("control").parse_args(["control", "--mode", mode])))
    assert plans["sim"].config.sim.mode == plans["motor"].config.sim.mode == mode


def _poses(messages, key: str, body: bool) -> list[tuple[float, float, float]]:
    found = []
    for message in messages:
        if message.topic != key:
            continue
        if body:
            data = decode(TimedDoubleSeq, message.data).data
            found.append((data[0], data[1], 0.0))
        else:
            pose = decode(TimedPosition, message.data)
            found.append((pose.x, pose.y, pose.theta))
    return found


@pytest.mark.slow
@pytest.mark.kinematic
def test_a_larger_right_wheel_in_the_sim_alone_curves_the_truth_while_odometry_goes_straight(tmp_path: Path):
    report = tmp_path / "run"
    result = subprocess.run(
        invent_command(
            "up",
            "--engine",
            "kinematic",
            "--composed",
            "--mode",
            "lockstep",
            "--scenario",
            "straight",
            "--listen",
            f"tcp/127.0.0.1:{free_port()}",
            "--report",
            str(report),
            # the stub's fixes (the sim's pose) would reset the odometry to the truth: one at the start only
            "--set",
            "localization.rate=0.01",
            "--sim-set",
            f"robot.radius_of_right_wheel={LARGER}",
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    output = result.stdout + result.stderr
    assert result.returncode == ExitStatus.OK, output[-4000:]
    assert "sim-set: the simulated robot differs from the description the other services read: " in output
    assert f"robot.radius_of_right_wheel={LARGER}" in output
    messages = read_messages(report / "run.mcap").messages
    truth = _poses(messages, KEYS.sim_body_pose, body=True)
    odometry = _poses(messages, KEYS.odometry_pose, body=False)
    assert truth and odometry
    # 2 m with the right wheel 5 % larger: the heading turns by about 0.05 x 2 / axle, the end ~0.2 m to the left
    assert truth[-1][1] > 0.15, truth[-1]
    assert abs(odometry[-1][1]) < 0.02 and abs(odometry[-1][2]) < 0.02, odometry[-1]
    assert abs(odometry[-1][0] - 2.0) < 0.05, odometry[-1]
    final = json.loads((report / "report.json").read_text())["final"]
    assert final["ground_truth"]["y"] > 0.15 and abs(final["odometry"]["y"]) < 0.02
