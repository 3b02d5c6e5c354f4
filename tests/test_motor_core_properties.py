"""MotorCore's invariants as hypothesis properties, and its input policy with its defaults (tests/test_motor_core.py
has the hand-computed values and the helpers).

Default robot: r = 0.1 m, lengthOfAxle 0.441 m (b = 0.2205 m), gains Kp 5, Kd 2.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import PDGains
from services.clock.sim_time import GAP_ADOPTION_SAMPLES
from services.config import InputConfig, MotorConfig, RobotConfig, TargetAngleMode
from services.motor.core import MotorCore, MotorState
from services.motor.sim_pose import SimPoseConverter
from tests.test_motor_core import MS, SEED_LAW, core, running, yaw_pose

# --- properties ----------------------------------------------------------------------------------

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False)
gain = st.floats(min_value=0.0, max_value=100.0)
speed = st.floats(min_value=-2.0, max_value=2.0)
step_ns = st.integers(min_value=100_000, max_value=50 * MS)


@given(vx=speed, w=speed, kp=gain, kd=gain, dt_ns=step_ns, q0=st.floats(-100, 100))
def test_seed_mode_at_target_speed_leaves_only_the_p_lead(vx, w, kp, kd, dt_ns, q0):
    """Wheels already at the target speed: the D term vanishes, and the seed's q_ref - q is
    (dq_ref + dq) * dt / 2 = dq_ref * dt, so the torque is Kp * dq_ref * dt (zero when Kp = 0
    or the target is zero): the seed's P term is only a one-step lead, not a position loop."""
    motor_core = core(p_gain_l=kp, p_gain_r=kp, d_gain_l=kd, d_gain_r=kd, target_angle=TargetAngleMode.SEED)
    motor_core.set_target(vx, w)
    motor_core.step(0, [q0, q0])
    dt = dt_ns / 1e9
    b, r = 0.2205, 0.1
    dq_ref = ((vx - b * w) / r, (vx + b * w) / r)
    torques = motor_core.step(dt_ns, [q0 + dq_ref[0] * dt, q0 + dq_ref[1] * dt])
    for torque, target in zip(torques, dq_ref, strict=True):
        assert torque == pytest.approx(kp * target * dt, abs=1e-12 * (1 + kd + kp) * (1 + abs(q0)) / dt)
    if kp == 0.0 or (vx == 0.0 and w == 0.0):
        assert torques == pytest.approx([0.0, 0.0], abs=1e-12 * (1 + kd) * (1 + abs(q0)) / dt)


@given(x=finite, y=finite, z=finite, yaw=st.floats(-10.0, 10.0))
def test_pose_conversion_is_exact_for_any_pure_yaw(x, y, z, yaw):
    pose = SimPoseConverter()(yaw_pose(x, y, z, yaw))
    assert pose[:3] == [x, y, z]
    assert math.remainder(pose[3] - yaw, math.tau) == pytest.approx(0.0, abs=1e-12)


@given(
    x=finite,
    y=finite,
    yaw=st.floats(-10.0, 10.0),
    dx=st.floats(-1.0, 1.0),
    dy=st.floats(-1.0, 1.0),
    dtheta=st.floats(-4.0, 4.0),
)
def test_pose_offset_is_the_offset_vector_turned_by_the_yaw(x, y, yaw, dx, dy, dtheta):
    X, Y, _, theta = SimPoseConverter(dx, dy, dtheta)(yaw_pose(x, y, 0.0, yaw))
    c, s = math.cos(yaw), math.sin(yaw)
    assert X == pytest.approx(x + c * dx - s * dy, abs=1e-9)
    assert Y == pytest.approx(y + s * dx + c * dy, abs=1e-9)
    assert -math.pi < theta <= math.pi
    assert math.remainder(theta - yaw - dtheta, math.tau) == pytest.approx(0.0, abs=1e-12)


joint_count = st.integers(min_value=2, max_value=6)


@st.composite
def wheel_layout(draw):
    count = draw(joint_count)
    left = draw(st.integers(0, count - 1))
    right = draw(st.integers(0, count - 1).filter(lambda i: i != left))
    return count, RobotConfig(left_wheel_id=left, right_wheel_id=right)


@given(
    layout=wheel_layout(),
    samples=st.lists(st.tuples(step_ns, st.lists(st.floats(-10, 10), min_size=6, max_size=6)), max_size=8),
    events=st.lists(st.sampled_from(["target", "start", "finish", "stop", "clear", "none"]), min_size=8, max_size=8),
)
def test_torque_vector_matches_the_input_and_is_zero_off_the_wheels(layout, samples, events):
    count, robot = layout
    motor_core = core(robot)
    stamp = 0
    for (dt_ns, angles), event in zip(samples, events, strict=False):
        if event == "target":
            motor_core.set_target(0.3, 0.4)
        elif event != "none":
            getattr(motor_core, event)()
        stamp += dt_ns
        state = motor_core.state
        torques = motor_core.step(stamp, angles[:count])
        assert len(torques) == count
        wheels = {robot.left_wheel_id, robot.right_wheel_id}
        assert all(t == 0.0 for i, t in enumerate(torques) if i not in wheels)
        if state in (MotorState.IDLE, MotorState.FINISHED):
            assert torques == [0.0] * count


@given(
    targets=st.lists(st.tuples(speed, speed), min_size=1, max_size=20),
    dt_ns=step_ns,
    max_v=st.floats(0.01, 1.0),
    max_a=st.floats(0.01, 5.0),
)
def test_limited_command_respects_velocity_and_acceleration(targets, dt_ns, max_v, max_a):
    motor_core = running(max_vx=max_v, max_ax=max_a, max_w=max_v, max_aw=max_a, command_timeout=0.0)
    previous = (0.0, 0.0)
    dt = dt_ns / 1e9
    for k, (vx, w) in enumerate(targets, start=1):
        motor_core.set_target(vx, w)
        motor_core.step(k * dt_ns, [0.0, 0.0])
        for now, before in zip(motor_core.command, previous, strict=True):
            assert abs(now) <= max_v
            assert abs(now - before) <= max_a * dt * (1 + 1e-9)
        previous = motor_core.command


@given(
    vx=speed,
    wheel_angles=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=10),
    dt_ns=step_ns,
)
def test_integrated_target_angle_is_anchor_plus_integral_of_target_speed(vx, wheel_angles, dt_ns):
    """Whatever the wheels do, q_ref integrates the target speed from its anchor (the first cycle)."""
    motor_core = running(vx=vx, target_angle=TargetAngleMode.INTEGRATED, command_timeout=0.0)
    dt = dt_ns / 1e9
    dq_ref = vx / 0.1
    motor_core.step(dt_ns, [wheel_angles[0]] * 2)
    anchor = motor_core.q_ref[0]
    for k, q in enumerate(wheel_angles[1:], start=1):
        motor_core.step((k + 1) * dt_ns, [q, q])
        assert motor_core.q_ref[0] == pytest.approx(anchor + dq_ref * dt * k, abs=1e-9)


@given(
    samples=st.lists(st.tuples(step_ns, st.floats(-1.0, 1.0)), min_size=2, max_size=10),
    bad_at=st.integers(0, 9),
)
def test_a_bad_sample_changes_nothing(samples, bad_at):
    assume(bad_at < len(samples))
    clean, noisy = running(vx=0.4, w=0.2), running(vx=0.4, w=0.2)
    stamp = 0
    for k, (dt_ns, q) in enumerate(samples):
        stamp += dt_ns
        if k == bad_at:
            with pytest.raises(BadInput):
                noisy.step(stamp - dt_ns, [5.0, 5.0])
            with pytest.raises(BadInput):
                noisy.step(stamp, [5.0])
        assert noisy.step(stamp, [q, -q]) == clean.step(stamp, [q, -q])


@given(
    before=st.lists(st.tuples(step_ns, st.floats(-10.0, 10.0)), max_size=6),
    after=st.lists(st.tuples(step_ns, st.floats(-10.0, 10.0)), min_size=1, max_size=6),
    new_start_ns=st.integers(0, 10**12),
    target=st.tuples(speed, speed),
)
def test_after_a_restart_the_torques_are_those_of_a_fresh_core(before, after, new_start_ns, target):
    """Whatever came before (and wherever the new clock starts), a restarted core answers the
    new stream exactly like a core that never saw the old one."""
    restarted, fresh = core(command_timeout=0.0), core(command_timeout=0.0)
    restarted.set_target(*target)
    stamp = 0
    for dt_ns, q in before:
        stamp += dt_ns
        restarted.step(stamp, [q, -q])
    restarted.restart_time_base()
    fresh.set_target(*target)
    stamp = new_start_ns
    for dt_ns, q in after:
        assert restarted.step(stamp, [q, 2 * q]) == fresh.step(stamp, [q, 2 * q])
        stamp += dt_ns


# --- the input policy, with its defaults --------------------------------------------------------


def test_a_stamp_beyond_the_horizon_is_bad_and_does_not_move_the_time_base():
    motor_core = running(vx=0.5, limits=InputConfig())
    with pytest.raises(BadInput, match="ahead of the time base"):
        motor_core.step(100_000 * 1000 * MS, [0.0, 0.0])
    torques = motor_core.step(1 * MS, [0.0005, 0.0005])  # the genuine next sample is still taken
    assert torques != [0.0, 0.0] and motor_core.wheel_angle_samples == 2


def test_a_wheel_angle_jump_beyond_the_plausible_wheel_speed_is_bad():
    motor_core = running(vx=0.5, limits=InputConfig(max_wheel_speed=50.0))
    with pytest.raises(BadInput, match="max_wheel_speed"):
        motor_core.step(50 * MS, [1e6, 1e6])
    assert motor_core.q == (0.0, 0.0)
    motor_core.step(50 * MS, [2.4, 2.4])  # 48 rad/s: plausible


def test_targets_are_checked_against_the_wheel_angle_time_and_the_wheel_speed_bound():
    motor_core = running(vx=0.5, limits=InputConfig(), command_timeout=0.5)
    for stamp_ns, vx, reason in (
        (2_000 * MS, 0.1, "ahead of the wheel-angle time"),
        (10**38, 0.1, "ahead of the wheel-angle time"),
        (0, 1e300, "max_wheel_speed"),
    ):
        with pytest.raises(BadInput, match=reason):
            motor_core.set_target(vx, 0.0, stamp_ns)
    assert motor_core.target == (0.5, 0.0)
    motor_core.step(600 * MS, [0.3, 0.3])
    with pytest.raises(BadInput, match="older than"):
        motor_core.set_target(0.1, 0.0, 0)
    assert motor_core.set_target(2.0, 0.0, 600 * MS) is True, "beyond max_vx but plausible: the limit clamps it"


def test_gains_above_the_ceiling_are_bad_and_change_nothing():
    motor_core = running(limits=InputConfig(max_gain=1000.0))
    with pytest.raises(BadInput, match="max_gain"):
        motor_core.set_pd_gain(PDGains(p_gain_l=1e308, p_gain_r=5.0, d_gain_l=2.0, d_gain_r=2.0))
    assert motor_core.gains == PDGains(5.0, 5.0, 2.0, 2.0)


def test_the_default_limits_clamp_an_absurd_but_plausible_target():
    motor_core = MotorCore(RobotConfig(), MotorConfig(command_timeout=0.0))
    motor_core.set_target(4.0, 0.0)
    motor_core.step(0, [0.0, 0.0])
    for k in range(1, 2001):
        motor_core.step(k * MS, [0.0, 0.0])
    assert motor_core.command == (1.0, 0.0), "max_vx 1 m/s, reached at max_ax 2 m/s^2 within 0.5 s"


def test_a_non_finite_torque_is_never_returned():
    """Unreachable within the default input bounds; guarded all the same."""
    motor_core = running(vx=0.5)
    motor_core.set_pd_gain(PDGains(p_gain_l=1e300, p_gain_r=1e300, d_gain_l=1e300, d_gain_r=1e300))
    torques = motor_core.step(1 * MS, [1e10, 1e10])
    assert torques == [0.0, 0.0] and motor_core.nonfinite_torques == 1


@given(st.floats(-0.5, 0.5), st.floats(-1.0, 1.0), st.integers(1, 20))
def test_a_target_applies_from_the_first_sample_after_its_stamp_whenever_it_arrives(vx, w, target_step):
    """Lockstep: the drive's target stamped t may reach the motor before or after the wheel angles
    of t; the torques are the same, bit for bit."""

    def torques(target_before_its_sample: bool) -> list[list[float]]:
        motor_core = core(**SEED_LAW)
        motor_core.set_target(0.1, 0.0, 0)
        out = []
        for k in range(target_step + 10):
            if k == target_step and target_before_its_sample:
                motor_core.set_target(vx, w, target_step * MS)
            out.append(motor_core.step(k * MS, [0.001 * k, 0.002 * k]))
            if k == target_step and not target_before_its_sample:
                motor_core.set_target(vx, w, target_step * MS)
        return out

    assert torques(True) == torques(False)


def test_a_target_waiting_for_its_sample_is_dropped_by_an_emergency_stop():
    motor_core = running(vx=0.5)
    motor_core.set_target(0.3, 0.0, 5 * MS)
    motor_core.stop()
    motor_core.clear()
    motor_core.step(6 * MS, [0.0, 0.0])
    assert motor_core.target == (0.0, 0.0)


def test_wheel_angles_back_after_a_gap_are_taken_again_from_rest_at_the_fifth_steady_sample():
    motor = MotorCore(RobotConfig(), MotorConfig(), InputConfig())
    motor.start()
    motor.set_target(0.2, 0.0)
    horizon_ns = InputConfig().stamp_horizon_ns
    for step in range(10):
        motor.step(step * 1_000_000, [0.001 * step, 0.001 * step])
    back_ns = 9_000_000 + 3 * horizon_ns
    for index in range(GAP_ADOPTION_SAMPLES - 1):
        with pytest.raises(BadInput, match="ahead of the time base"):
            motor.step(back_ns + index * 1_000_000, [0.5, 0.5])
    taken = motor.step(back_ns + (GAP_ADOPTION_SAMPLES - 1) * 1_000_000, [0.5, 0.5])
    assert taken == [0.0, 0.0], "the first sample after the gap: no Δt across it, zero torque"
    assert any(motor.step(back_ns + (GAP_ADOPTION_SAMPLES + 1) * 1_000_000, [0.501, 0.501])), "controlled again"
