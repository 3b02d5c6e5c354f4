"""MotorCore against hand-computed values (tests/test_motor_core_properties.py: its properties).

Default robot: r = 0.1 m, lengthOfAxle 0.441 m (b = 0.2205 m), gains Kp 5, Kd 2.
"""

from __future__ import annotations

import math

import pytest

from schemas.codec import BadInput
from schemas.messages import PDGains
from schemas.status import Velocity
from services.config import CalibratedGeometry, InputConfig, MotorConfig, OdometryConfig, RobotConfig, TargetAngleMode
from services.motor.core import MotorCore, MotorState
from services.motor.sim_pose import SimPoseConverter

MS = 1_000_000
"""One millisecond in nanoseconds."""


SEED_LAW = {"max_vx": None, "max_ax": None, "max_w": None, "max_aw": None}
"""The seed's law has no velocity or acceleration limits (the defaults have them): the
hand-computed values below are the seed's unless a test names limits."""


ANY_INPUT = InputConfig(stamp_horizon=1e9, max_wheel_speed=1e300, max_gain=1e300)
"""The control law is tested on whatever input reaches it; the input policy (stamp horizon,
plausible wheel speeds, gain ceiling) has tests of its own, with its defaults."""


def core(robot: RobotConfig | None = None, limits: InputConfig = ANY_INPUT, **motor: object) -> MotorCore:
    return MotorCore(robot or RobotConfig(), MotorConfig(**{**SEED_LAW, **motor}), limits)


def running(robot: RobotConfig | None = None, vx: float = 0.0, w: float = 0.0, **motor: object) -> MotorCore:
    """A core that saw its first sample (angles 0 at t = 0) and a target: the next step controls."""
    motor_core = core(robot, **motor)
    motor_core.set_target(vx, w)
    angles = [0.0] * (max(motor_core.robot.left_wheel_id, motor_core.robot.right_wheel_id) + 1)
    assert motor_core.step(0, angles) == [0.0] * len(angles)
    assert motor_core.state is MotorState.RUNNING
    return motor_core


def yaw_pose(x: float, y: float, z: float, yaw: float) -> list[float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return [x, y, z, c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]


# --- torque: hand-computed -------------------------------------------------------------------


def test_straight_w0_hand_computed():
    motor_core = running(vx=0.5)
    # dq_ref = 0.5 / 0.1 = 5 both; dq = (4, 6); q_ref - q = (5 + dq) * 0.001 / 2
    torques = motor_core.step(1 * MS, [0.004, 0.006])
    assert motor_core.dq_ref == pytest.approx((5.0, 5.0))
    assert motor_core.dq == pytest.approx((4.0, 6.0))
    assert motor_core.q_ref == pytest.approx((0.0085, 0.0115))
    assert torques == pytest.approx([5 * 0.0045 + 2 * 1.0, 5 * 0.0055 + 2 * -1.0])
    assert torques == pytest.approx([2.0225, -1.9725])


def test_spin_in_place_hand_computed():
    motor_core = running(w=1.0)
    # dq_ref = (-0.2205, +0.2205) / 0.1; dt = 2 ms, dq = (-2, 2); q_ref - q = (dq_ref + dq) * 0.001
    torques = motor_core.step(2 * MS, [-0.004, 0.004])
    assert motor_core.dq_ref == pytest.approx((-2.205, 2.205))
    assert torques == pytest.approx([-0.431025, 0.431025])


def test_different_left_and_right_radii_hand_computed():
    robot = RobotConfig(radius_of_left_wheel=0.1, radius_of_right_wheel=0.2)
    motor_core = running(robot, vx=0.5, w=1.0)
    # dq_ref_L = (0.5 - 0.2205) / 0.1 = 2.795, dq_ref_R = (0.5 + 0.2205) / 0.2 = 3.6025; wheels still
    torques = motor_core.step(1 * MS, [0.0, 0.0])
    assert motor_core.dq_ref == pytest.approx((2.795, 3.6025))
    assert torques == pytest.approx([5 * 2.795 * 0.0005 + 2 * 2.795, 5 * 3.6025 * 0.0005 + 2 * 3.6025])
    assert torques == pytest.approx([5.5969875, 7.21400625])


def test_the_calibrated_geometry_turns_commands_into_wheel_speeds():
    """The odometry's calibration multipliers apply to the motor's conversion too (as
    diff_drive_controller's do): a calibrated robot is commanded with the lengths it has."""
    calibration = OdometryConfig(left_radius_scale=0.995, right_radius_scale=1.005, axle_scale=1.02)
    robot = RobotConfig()
    motor_core = MotorCore(robot, MotorConfig(**SEED_LAW), ANY_INPUT, CalibratedGeometry.of(robot, calibration))
    motor_core.set_target(0.5, 1.0)
    motor_core.step(0, [0.0, 0.0])
    motor_core.step(1 * MS, [0.0, 0.0])
    # b = 0.441 * 1.02 / 2 = 0.22491; dq_ref_L = (0.5 - 0.22491) / 0.0995, dq_ref_R = (0.5 + 0.22491) / 0.1005
    assert motor_core.dq_ref == pytest.approx((2.764723618, 7.213034826))
    assert motor_core.status().geometry["half_axle"] == pytest.approx(0.22491)


def test_non_default_wheel_ids_in_a_three_joint_vector():
    robot = RobotConfig(left_wheel_id=1, right_wheel_id=0)
    motor_core = core(robot)
    motor_core.set_target(0.5, 0.0)
    assert motor_core.step(0, [0.0, 0.0, 0.7]) == [0.0, 0.0, 0.0]
    # the straight case with left and right swapped in the vector; joint 2 is no wheel
    torques = motor_core.step(1 * MS, [0.006, 0.004, 0.9])
    assert len(torques) == 3
    assert torques[:2] == pytest.approx([-1.9725, 2.0225])
    assert torques[2] == 0.0


def test_wheel_id_out_of_range_is_bad_input():
    motor_core = core(RobotConfig(left_wheel_id=0, right_wheel_id=2))
    with pytest.raises(BadInput, match="need at least 3"):
        motor_core.step(0, [0.0, 0.0])
    assert motor_core.wheel_angle_samples == 0


def test_set_pd_gain_applies_from_the_next_step():
    motor_core = running(vx=0.5)
    motor_core.step(1 * MS, [0.004, 0.006])
    motor_core.set_pd_gain(PDGains(p_gain_l=10.0, p_gain_r=0.0, d_gain_l=1.0, d_gain_r=3.0))
    # dq = (4, 4); q_ref - q = (5 + 4) * 0.0005 = 0.0045; dq_ref - dq = 1
    torques = motor_core.step(2 * MS, [0.008, 0.010])
    assert torques == pytest.approx([10 * 0.0045 + 1 * 1.0, 0 * 0.0045 + 3 * 1.0])


# --- target_angle modes ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("mode", "expected"),
    [
        # seed: q_ref restarts from the measured q: q_ref - q = (5 + 2) * 0.0005 = 0.0035 each lagging cycle
        (TargetAngleMode.SEED, [2.0225, 5 * 0.0035 + 2 * 3, 5 * 0.0035 + 2 * 3]),
        # integrated: q_ref = 0.0085, then + 5 * 0.001 per cycle, so the lag accumulates in the P term:
        # cycle 2: 0.0135 - 0.006 = 0.0075; cycle 3: 0.0185 - 0.008 = 0.0105
        (TargetAngleMode.INTEGRATED, [2.0225, 5 * 0.0075 + 2 * 3, 5 * 0.0105 + 2 * 3]),
    ],
)
def test_target_angle_modes_hand_computed(mode, expected):
    motor_core = running(vx=0.5, target_angle=mode)
    torques = [motor_core.step(k * MS, [q, q])[0] for k, q in ((1, 0.004), (2, 0.006), (3, 0.008))]
    assert torques == pytest.approx(expected)


def test_integrated_mode_reanchors_on_stop():
    motor_core = running(vx=0.5, target_angle=TargetAngleMode.INTEGRATED)
    for k, q in ((1, 0.004), (2, 0.006), (3, 0.008)):
        motor_core.step(k * MS, [q, q])
    motor_core.stop()
    # anchored again at the measured angle: q_ref = q + (0 + dq) * dt / 2, no catch-up of the lag
    motor_core.step(4 * MS, [0.010, 0.010])
    assert motor_core.q_ref == pytest.approx((0.010 + 2 * 0.0005, 0.010 + 2 * 0.0005))


# --- states and Motor methods ----------------------------------------------------------------


def test_first_sample_only_initialises():
    motor_core = core()
    motor_core.set_target(0.5, 0.0)
    assert motor_core.step(5 * MS, [1.0, 2.0]) == [0.0, 0.0]
    assert motor_core.dq is None and motor_core.q_ref is None
    assert motor_core.state is MotorState.RUNNING


def test_idle_without_target_gives_zero_torque():
    motor_core = core()
    motor_core.step(0, [0.0, 0.0])
    assert motor_core.step(1 * MS, [0.004, 0.006]) == [0.0, 0.0]
    assert motor_core.state is MotorState.IDLE
    assert motor_core.cycle_state is MotorState.IDLE


def test_finish_coasts_until_start():
    motor_core = running(vx=0.5)
    motor_core.finish()
    assert motor_core.state is MotorState.FINISHED
    assert motor_core.step(1 * MS, [0.004, 0.006]) == [0.0, 0.0]
    motor_core.set_target(0.4, 0.0)
    assert motor_core.step(2 * MS, [0.008, 0.012]) == [0.0, 0.0]
    motor_core.start()
    assert motor_core.state is MotorState.RUNNING
    # dq = (4, 6), dq_ref = 4: back under control with the latest target
    assert motor_core.step(3 * MS, [0.012, 0.018]) == pytest.approx([5 * 0.004, 5 * 0.005 + 2 * -2.0])


def test_stop_brakes_and_ignores_targets_until_clear():
    motor_core = running(vx=0.5)
    motor_core.stop()
    assert motor_core.state is MotorState.STOPPED
    assert motor_core.set_target(1.0, 0.5) is False
    assert motor_core.targets_ignored == 1
    # wheels at 5 rad/s, target 0: q_ref - q = 5 * 0.0005, dq_ref - dq = -5
    torques = motor_core.step(1 * MS, [0.005, 0.005])
    assert motor_core.command == (0.0, 0.0)
    assert torques == pytest.approx([5 * 0.0025 - 10.0] * 2)
    motor_core.clear()
    assert motor_core.state is MotorState.RUNNING
    assert motor_core.target == (0.0, 0.0)
    assert motor_core.set_target(0.3, 0.0) is True
    motor_core.step(2 * MS, [0.010, 0.010])
    assert motor_core.command == (0.3, 0.0)


def test_clear_returns_to_the_underlying_state():
    motor_core = core()
    motor_core.stop()
    assert motor_core.state is MotorState.STOPPED
    motor_core.clear()
    assert motor_core.state is MotorState.IDLE
    motor_core.finish()
    motor_core.stop()
    motor_core.clear()
    assert motor_core.state is MotorState.FINISHED


def test_dt_not_positive_is_bad_input_and_changes_nothing():
    motor_core = running(vx=0.5)
    motor_core.step(1 * MS, [0.004, 0.006])
    for stamp in (1 * MS, 0):
        with pytest.raises(BadInput, match="<= 0"):
            motor_core.step(stamp, [9.0, 9.0])
    assert motor_core.wheel_angle_samples == 2
    # dq from the last good sample: (0.008 - 0.004) / 0.001 = 4 on both wheels
    motor_core.step(2 * MS, [0.008, 0.010])
    assert motor_core.dq == pytest.approx((4.0, 4.0))


# --- a restarted simulator ------------------------------------------------------------------------


def test_restart_time_base_initialises_again_and_keeps_gains_target_and_counters():
    motor_core = running(vx=0.5)
    motor_core.set_pd_gain(PDGains(1.0, 2.0, 3.0, 4.0))
    motor_core.step(400 * MS, [2.0, 2.0])
    with pytest.raises(BadInput, match="<= 0"):
        motor_core.step(0, [0.0, 0.0])
    motor_core.restart_time_base()
    assert motor_core.time_ns is None and motor_core.state is MotorState.IDLE, (
        "no wheel angles in the new time base yet"
    )
    assert motor_core.step(0, [0.0, 0.0]) == [0.0, 0.0], "the new clock's 0 initialises like a first sample"
    assert motor_core.dq is None and motor_core.state is MotorState.RUNNING
    # the straight case with gains (1, 2, 3, 4): dq = (4, 6), dq_ref = 5, q_ref - q = (5 + dq) * 0.0005
    torques = motor_core.step(1 * MS, [0.004, 0.006])
    assert torques == pytest.approx([1 * 0.0045 + 3 * 1.0, 2 * 0.0055 + 4 * -1.0])
    assert motor_core.target == (0.5, 0.0)
    assert motor_core.wheel_angle_samples == 4 and motor_core.target_velocity_samples == 1


def test_restart_time_base_before_any_sample_changes_nothing():
    motor_core = core()
    motor_core.restart_time_base()
    assert motor_core.step(7 * MS, [1.0, 1.0]) == [0.0, 0.0]


@pytest.mark.parametrize("latch", ["stop", "finish"])
def test_restart_time_base_keeps_the_stop_and_finish_latches(latch):
    motor_core = running(vx=0.5)
    getattr(motor_core, latch)()
    state = motor_core.state
    motor_core.restart_time_base()
    assert motor_core.state is state
    motor_core.step(0, [0.0, 0.0])
    motor_core.step(1 * MS, [0.005, 0.005])
    assert motor_core.state is state
    if latch == "stop":
        assert motor_core.command == (0.0, 0.0) and motor_core.set_target(0.5, 0.0) is False


def test_restart_time_base_restarts_the_target_age_but_not_a_timeout():
    motor_core = running(vx=0.5)  # target at wheel-angle time 0; timeout 0.5 s
    motor_core.step(300 * MS, [0.0, 0.0])
    motor_core.restart_time_base()
    motor_core.step(0, [0.0, 0.0])  # the target's age counts from here
    motor_core.step(500 * MS, [0.0, 0.0])
    assert motor_core.command == (0.5, 0.0)
    motor_core.step(501 * MS, [0.0, 0.0])
    assert motor_core.command == (0.0, 0.0) and motor_core.command_timeouts == 1
    motor_core.restart_time_base()
    motor_core.step(0, [0.0, 0.0])
    motor_core.step(1 * MS, [0.0, 0.0])
    assert motor_core.command == (0.0, 0.0), "a timed-out command stays so across a restart"
    assert motor_core.command_timed_out and motor_core.command_timeouts == 1
    motor_core.set_target(0.2, 0.0)
    motor_core.step(2 * MS, [0.0, 0.0])
    assert motor_core.command == (0.2, 0.0)


def test_restart_time_base_resumes_control_from_rest():
    motor_core = running(vx=0.5, max_ax=1.0, target_angle=TargetAngleMode.INTEGRATED, command_timeout=0.0)
    for k in range(1, 50):
        motor_core.step(k * MS, [0.0, 0.0])
    assert motor_core.command[0] == pytest.approx(0.049)
    motor_core.restart_time_base()
    motor_core.step(0, [3.0, 3.0])
    motor_core.step(1 * MS, [3.0, 3.0])
    assert motor_core.command == pytest.approx((0.001, 0.0)), "the ramp starts from zero again"
    assert motor_core.q_ref[0] == pytest.approx(3.0 + 0.01 * 0.0005), "integrated mode re-anchors at q"


# --- command timeout and limits --------------------------------------------------------------


def test_command_timeout_brakes_once_then_rearms():
    motor_core = running(vx=0.5)  # target arrived at wheel-angle time 0; timeout 0.5 s
    motor_core.step(500 * MS, [0.0, 0.0])
    assert motor_core.command == (0.5, 0.0)
    motor_core.step(501 * MS, [0.0, 0.0])
    assert motor_core.command == (0.0, 0.0)
    assert motor_core.command_timed_out and motor_core.command_timeouts == 1
    motor_core.step(502 * MS, [0.0, 0.0])
    assert motor_core.command_timeouts == 1
    motor_core.set_target(0.2, 0.0)
    motor_core.step(503 * MS, [0.0, 0.0])
    assert motor_core.command == (0.2, 0.0)
    assert not motor_core.command_timed_out


def test_command_timeout_zero_disables():
    motor_core = running(vx=0.5, command_timeout=0.0)
    motor_core.step(100_000 * MS, [0.0, 0.0])
    assert motor_core.command == (0.5, 0.0)
    assert motor_core.command_timeouts == 0


def test_velocity_limits_clamp_the_command():
    motor_core = running(vx=0.5, w=-2.0, max_vx=0.3, max_w=1.0)
    motor_core.step(1 * MS, [0.0, 0.0])
    assert motor_core.command == (0.3, -1.0)


def test_acceleration_limits_ramp_the_command():
    motor_core = running(vx=0.5, w=1.0, max_ax=1.0, max_aw=2.0)
    motor_core.step(1 * MS, [0.0, 0.0])
    assert motor_core.command == pytest.approx((0.001, 0.002))
    motor_core.step(3 * MS, [0.0, 0.0])
    assert motor_core.command == pytest.approx((0.003, 0.006))
    motor_core.stop()
    motor_core.step(4 * MS, [0.0, 0.0])
    assert motor_core.command == (0.0, 0.0), "an emergency stop bypasses the acceleration limit"
    motor_core.clear()
    motor_core.set_target(0.5, 1.0)
    motor_core.step(5 * MS, [0.0, 0.0])
    assert motor_core.command == pytest.approx((0.001, 0.002)), "after clear the ramp starts from zero"


# --- body pose ---------------------------------------------------------------------------------


def test_pose_without_offsets_is_the_model_pose():
    assert SimPoseConverter()(yaw_pose(1.0, 2.0, 0.3, 0.5)) == pytest.approx([1.0, 2.0, 0.3, 0.5])


def test_seed_rh0_offsets_hand_computed():
    rh0 = core(simulated_offset_y=0.045795, simulated_offset_angle=1.5708)
    # model unrotated: its forward (+y) is world +y, so heading 1.5708; axle centre 0.045795 along +y
    assert rh0.sim_pose(yaw_pose(1.0, 2.0, 0.3, 0.0)) == pytest.approx([1.0, 2.045795, 0.3, 1.5708], abs=1e-12)
    # model turned by -pi/2: its forward is world +x, heading ~0, axle centre 0.045795 along +x
    x, y, z, theta = rh0.sim_pose([1.0, 2.0, 0.3, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    assert (x, y, z) == pytest.approx((1.045795, 2.0, 0.3), abs=1e-12)
    assert theta == pytest.approx(1.5708 - math.pi / 2, abs=1e-12)
    assert rh0.body_pose_samples == 2


def test_heading_wraps_into_minus_pi_pi():
    assert SimPoseConverter(offset_angle=0.5)(yaw_pose(0, 0, 0, 3.0))[3] == pytest.approx(3.5 - 2 * math.pi)
    assert SimPoseConverter(offset_angle=-0.5)(yaw_pose(0, 0, 0, -3.0))[3] == pytest.approx(2 * math.pi - 3.5)
    # a half turn with A12 = 0.0: atan2(-0.0, -1) = -pi, reported as +pi
    half_turn = [0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]
    assert SimPoseConverter()(half_turn)[3] == math.pi


@pytest.mark.parametrize("length", [11, 13, 0])
def test_body_pose_of_wrong_length_is_bad_input(length):
    motor_core = core()
    with pytest.raises(BadInput, match="expected 12"):
        motor_core.sim_pose([0.0] * length)
    assert motor_core.body_pose_samples == 0


def test_status_reports_state_gains_geometry_and_counters():
    motor_core = running(vx=0.5, max_vx=1.0)
    motor_core.step(1 * MS, [0.0, 0.0])
    status = motor_core.status()
    assert status.state == "running"
    assert status.target_angle == TargetAngleMode.SEED
    assert status.gains == {"p_gain_l": 5.0, "p_gain_r": 5.0, "d_gain_l": 2.0, "d_gain_r": 2.0}
    assert status.geometry["length_of_axle"] == 0.441
    assert status.limits["max_vx"] == 1.0 and status.limits["max_ax"] is None
    assert status.target == Velocity(0.5, 0.0)
    assert status.counters.wheel_angle_samples == 2
    assert status.counters.target_velocity_samples == 1
